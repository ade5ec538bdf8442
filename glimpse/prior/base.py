"""The interface every unseen-part prior implements (paper Sec. 4.4; threestudio's guidance modules).

Stage 06 calls :meth:`UnseenPrior.losses` once per iteration, after the reconstruction loss is
formed, with the people being optimised; a prior returns named ``loss_*`` terms (already
weighted by its own config), which are added to the total. A prior that needs per-run state
(identity tokens, a diffusion pipeline) builds it in its constructor.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence

from torch import Tensor

from glimpse.humans.person import PersonGaussians


class UnseenPrior(ABC):
    """A prior over what no input view saw. ``name`` is its registry key (pipeline.yaml prior.kind)."""

    name: str

    @abstractmethod
    def losses(self, step: int, people: Sequence[PersonGaussians]) -> dict[str, Tensor]:
        """Weighted loss terms at global iteration ``step`` (1-based) for ``people``; keys start with ``loss_``."""
