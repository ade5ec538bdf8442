"""Priors over the unseen parts of people, registered by name (pipeline.yaml ``prior.kind``).

Registered here by explicit import; ``make_prior`` builds one, ``resolve_prior_kind`` turns
``auto`` into a concrete kind (CONTRACTS.md "Default prior").
"""

from __future__ import annotations

from glimpse.errors import ConfigError
from glimpse.prior.base import UnseenPrior
from glimpse.prior.none import NoPrior

PRIORS: dict[str, type[UnseenPrior]] = {NoPrior.name: NoPrior}
AUTO_ORDER = ("sds", "surface", "none")
PLANNED = {"surface": "issue #10 (the offline prior)", "sds": "issue #12 (the diffusion prior)"}


def resolve_prior_kind(kind: str) -> str:
    """``auto`` -> the first registered of sds (which will also need diffusion weights and CUDA),
    surface, none; any other kind is returned as given."""
    if kind != "auto":
        return kind
    return next(name for name in AUTO_ORDER if name in PRIORS)


def make_prior(kind: str) -> UnseenPrior:
    """The prior registered under ``kind`` (after resolving ``auto``); unknown names list the known ones."""
    name = resolve_prior_kind(kind)
    if name in PRIORS:
        return PRIORS[name]()
    if name in PLANNED:
        raise ConfigError(f"pipeline.yaml prior.kind: {name!r} is not available yet (it arrives with {PLANNED[name]}); "
                          f"registered priors: {', '.join(PRIORS)} (or auto)")
    raise ConfigError(f"pipeline.yaml prior.kind: unknown prior {name!r}; registered priors: "
                      f"{', '.join(PRIORS)} (or auto)")


__all__ = ["PRIORS", "UnseenPrior", "make_prior", "resolve_prior_kind"]
