"""``prior.kind: none``: no prior. Parts no input view saw keep whatever the reconstruction loss and
the hard-surface term leave there (the paper's ablation without a prior, Table 4)."""

from __future__ import annotations

from collections.abc import Sequence

from torch import Tensor

from glimpse.humans.person import PersonGaussians
from glimpse.prior.base import PriorContext, UnseenPrior


class NoPrior(UnseenPrior):
    name = "none"

    def __init__(self, context: PriorContext | None = None, config: object = None):
        del context, config  # nothing to prepare

    def losses(self, step: int, people: Sequence[PersonGaussians]) -> dict[str, Tensor]:
        return {}
