"""The interface every unseen-part prior implements (paper Sec. 4.4; threestudio's guidance modules).

Stage 06 builds the prior once with a :class:`PriorContext` (the people, what the input views saw
of each body, the body model) and its own pipeline.yaml section, then calls
:meth:`UnseenPrior.losses` once per iteration, after the reconstruction loss is formed, with the
people present in that iteration's view; a prior returns named ``loss_*`` terms (already weighted
by its own config), which are added to the total. After densification or pruning changes a
person's Gaussians the trainer calls :meth:`UnseenPrior.gaussians_changed`. Whatever a prior caches
between iterations goes into stage 06's checkpoints through ``state_dict``/``load_state_dict``, so a
resumed run ends where an uninterrupted one does.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from torch import Tensor

from glimpse.body.model import BodyModel
from glimpse.humans.person import PersonGaussians
from glimpse.humans.visibility import BodyVisibility
from glimpse.render.config import RenderConfig


@dataclass
class PriorContext:
    """What a prior may use: every person being trained, each person's vertex visibility in the input
    frames (by pid), the body model, the render settings, the run's seed, and the schedule's scaling
    of an iteration count (JointConfig.scaled)."""

    people: list[PersonGaussians]
    visibility: dict[str, BodyVisibility]
    body_model: BodyModel
    render: RenderConfig
    seed: int
    scaled: Callable[[int], int]


class UnseenPrior(ABC):
    """A prior over what no input view saw. ``name`` is its registry key (pipeline.yaml prior.kind)."""

    name: str

    @abstractmethod
    def losses(self, step: int, people: Sequence[PersonGaussians]) -> dict[str, Tensor]:
        """Weighted loss terms at global iteration ``step`` (1-based) for ``people``; keys start with ``loss_``."""

    def gaussians_changed(self, person: PersonGaussians) -> None:
        """``person``'s Gaussians were densified or pruned: rows cached per Gaussian are stale."""

    def state_dict(self) -> dict:
        return {}

    def load_state_dict(self, state: dict) -> None:
        """Restore what :meth:`state_dict` returned."""
