"""The interface every unseen-part prior implements (paper Sec. 4.4; threestudio's guidance modules).

Stage 06 builds the prior once with a :class:`PriorContext` (the people, what the input views saw
of each body, the body model) and its own pipeline.yaml section, then calls
:meth:`UnseenPrior.losses` once per iteration, after the reconstruction loss is formed, with the
people present in that iteration's view; a prior returns named ``loss_*`` terms (already weighted
by its own config), which are added to the total, the reconstruction terms weighted by
:meth:`UnseenPrior.recon_weight`; after the iteration's optimiser step, each of
:meth:`UnseenPrior.separate_losses` takes its own step on one person. After densification or pruning changes a
person's Gaussians the trainer calls :meth:`UnseenPrior.gaussians_changed`. Whatever a prior caches
between iterations goes into stage 06's checkpoints through ``state_dict``/``load_state_dict``, so a
resumed run ends where an uninterrupted one does.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from torch import Tensor

from glimpse.body.models import BodyModels
from glimpse.humans.person import PersonGaussians
from glimpse.humans.visibility import BodyVisibility
from glimpse.render.config import RenderConfig


@dataclass
class PriorContext:
    """What a prior may use: every person being trained, each person's vertex visibility in the input
    frames (by pid), each person's body model (one topology for all), the render settings, the run's seed,
    the schedule's scaling of an iteration count (JointConfig.scaled), stage 05's outputs and a folder for
    previews."""

    people: list[PersonGaussians]
    visibility: dict[str, BodyVisibility]
    body_models: BodyModels
    render: RenderConfig
    seed: int
    scaled: Callable[[int], int]
    identity_dir: Path | None = None  # stage 05's output folder (<pid>/identity/: the sds prior's identities)
    preview_dir: Path | None = None  # where a prior may write images of its guidance (the sds prior's previews)


class UnseenPrior(ABC):
    """A prior over what no input view saw. ``name`` is its registry key (pipeline.yaml prior.kind); a prior
    with parameters owns one pipeline.yaml ``section``, read strictly into its ``config_class`` and handed to
    its constructor (None for a prior without parameters)."""

    name: str
    section: str | None = None
    config_class: type | None = None

    @abstractmethod
    def losses(self, step: int, people: Sequence[PersonGaussians]) -> dict[str, Tensor]:
        """Weighted loss terms at global iteration ``step`` (1-based) for ``people``; keys start with ``loss_``."""

    def recon_weight(self, step: int) -> float:
        """The weight of the reconstruction loss (and the hard-surface term) at ``step``: 1 unless the prior
        rebalances them (the sds prior's lambda_recon)."""
        return 1.0

    def separate_losses(self, step: int) -> Iterator[tuple[int, Tensor]]:
        """Losses that take their own optimiser step after the iteration's, one per person (index into the
        context's people) and in turn: the trainer backpropagates each and steps that person's optimiser.
        None by default (the official code's SDS takes them)."""
        return iter(())

    def gaussians_changed(self, person: PersonGaussians) -> None:
        """``person``'s Gaussians were densified or pruned: rows cached per Gaussian are stale."""

    def report(self) -> dict:
        """Facts for stage 06's report (JSON-ready; empty by default)."""
        return {}

    def state_dict(self) -> dict:
        return {}

    def load_state_dict(self, state: dict) -> None:
        """Restore what :meth:`state_dict` returned."""
