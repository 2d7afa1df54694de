"""Name -> depth-prior factory, for configs and the CLI (``make_depth_prior("simulated", seed=1)``)."""

from __future__ import annotations

from typing import Callable

from .adapters import DepthAnywhereAdapter, ExportedDepthPrior, UniFuseAdapter, UniK3DAdapter
from .base import ConstantPrior, DepthPrior, GroundTruthPrior, NoPrior
from .files import FilePrior
from .simulated import SimulatedPrior

__all__ = ["DEPTH_PRIORS", "register_depth_prior", "make_depth_prior", "parse_depth_prior", "require_depth_prior"]

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


# The one positional argument a "name:value" spec fills in, per prior.
_SPEC_ARGUMENT = {"constant": ("depth", float), "file": ("name", str), "simulated": ("seed", int),
                  "exported": ("weights", str), "unik3d": ("weights", str), "depth_anywhere": ("weights", str),
                  "unifuse": ("weights", str)}


def parse_depth_prior(spec: str, **kwargs) -> DepthPrior:
    """A prior from a command-line spec: ``name`` or ``name:value`` (``constant:2.5``, ``exported:net.pt2``,
    ``unik3d:/models/unik3d-vitl``)."""
    name, sep, value = spec.partition(":")
    if sep:
        if name not in _SPEC_ARGUMENT:
            raise ValueError(f"depth prior {name!r} takes no ':value' (spec {spec!r})")
        key, kind = _SPEC_ARGUMENT[name]
        try:
            kwargs[key] = kind(value)
        except ValueError:
            raise ValueError(f"depth prior spec {spec!r}: {value!r} is not a valid {key}") from None
    return make_depth_prior(name, **kwargs)


for _cls in (NoPrior, GroundTruthPrior, ConstantPrior, SimulatedPrior, FilePrior, ExportedDepthPrior, UniK3DAdapter,
             DepthAnywhereAdapter, UniFuseAdapter):
    register_depth_prior(_cls.name, _cls)


MISSING_PRIOR_HELP = ("the model needs a depth prior for every input view and this dataset has none (its default "
                      "gives zeros, which renders black); choose one: {option}=gt (ground truth, an oracle), "
                      "{option}=constant:METRES, {option}=exported:NET.pt2 (any exported panorama depth network), "
                      "{option}=unik3d:WEIGHTS_DIR, or {option}=none to really run without one")


def require_depth_prior(dataset, option: str = "data.depth_prior") -> None:
    """Raise ``ValueError`` (one line, what to do) when ``dataset``'s *default* prior is all zeros; call
    it only when the user did not choose a prior (an explicit ``none`` is their decision)."""
    from .base import NoPrior

    if isinstance(getattr(dataset, "depth_prior", None), NoPrior):
        raise ValueError(MISSING_PRIOR_HELP.format(option=option))
