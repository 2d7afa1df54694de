"""Name -> depth-prior factory, for configs and the CLI (``make_depth_prior("simulated", seed=1)``)."""

from __future__ import annotations

from typing import Callable

from .adapters import DepthAnywhereAdapter, UniFuseAdapter, UniK3DAdapter
from .base import DepthPrior, GroundTruthPrior, NoPrior
from .files import FilePrior
from .simulated import SimulatedPrior

__all__ = ["DEPTH_PRIORS", "register_depth_prior", "make_depth_prior"]

DEPTH_PRIORS: dict[str, Callable[..., DepthPrior]] = {}


def register_depth_prior(name: str, factory: Callable[..., DepthPrior]) -> None:
    """Register a factory under ``name`` (re-registering a name is an error)."""
    if name in DEPTH_PRIORS:
        raise ValueError(f"depth prior {name!r} is already registered")
    DEPTH_PRIORS[name] = factory


def make_depth_prior(name: str, **kwargs) -> DepthPrior:
    """Instantiate the prior registered as ``name`` with ``kwargs``."""
    if name not in DEPTH_PRIORS:
        raise ValueError(f"unknown depth prior {name!r}; available: {sorted(DEPTH_PRIORS)}")
    return DEPTH_PRIORS[name](**kwargs)


for _cls in (NoPrior, GroundTruthPrior, SimulatedPrior, FilePrior, UniK3DAdapter, DepthAnywhereAdapter, UniFuseAdapter):
    register_depth_prior(_cls.name, _cls)
