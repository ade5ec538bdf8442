"""Priors over the unseen parts of people, registered by name (pipeline.yaml ``prior.kind``).

Registered here by explicit import, one line each in ``PRIORS``; each prior class names its own
pipeline.yaml section and config class (``section``, ``config_class``), which the pipeline's section table
takes from here. ``make_prior`` builds one with its config, ``resolve_prior_kind`` turns ``auto`` into a
concrete kind (CONTRACTS.md "Default prior").
"""

from __future__ import annotations

from glimpse.errors import ConfigError
from glimpse.prior.base import PriorContext, UnseenPrior
from glimpse.prior.none import NoPrior
from glimpse.prior.sds.prior import SDSPrior
from glimpse.prior.surface import SurfacePrior

PRIORS: dict[str, type[UnseenPrior]] = {NoPrior.name: NoPrior, SurfacePrior.name: SurfacePrior, SDSPrior.name: SDSPrior}
AUTO_ORDER = ("sds", "surface", "none")


def resolve_prior_kind(kind: str, diffusion_ready: bool = False) -> str:
    """``auto`` -> sds when ``diffusion_ready`` (weights configured and CUDA present, CONTRACTS.md), else the
    first registered of surface, none; any other kind is returned as given."""
    if kind != "auto":
        return kind
    return next(name for name in AUTO_ORDER if name in PRIORS and (name != "sds" or diffusion_ready))


def check_prior_kind(kind: str, diffusion_ready: bool = False) -> str:
    """The resolved kind, or a ConfigError naming what is registered."""
    name = resolve_prior_kind(kind, diffusion_ready)
    if name in PRIORS:
        return name
    raise ConfigError(f"pipeline.yaml prior.kind: unknown prior {name!r}; registered priors: "
                      f"{', '.join(PRIORS)} (or auto)")


def prior_sections() -> dict[str, type]:
    """pipeline.yaml section -> config class, of every registered prior that has parameters."""
    return {prior.section: prior.config_class for prior in PRIORS.values() if prior.section is not None}


def make_prior(kind: str, context: PriorContext, config: object | None) -> UnseenPrior:
    """The prior registered under the resolved ``kind``, built with ``config``: its section's typed config
    (``PRIORS[kind].section``), None for a prior without one."""
    return PRIORS[check_prior_kind(kind)](context, config)


__all__ = ["PRIORS", "PriorContext", "UnseenPrior", "check_prior_kind", "make_prior", "prior_sections",
           "resolve_prior_kind"]
