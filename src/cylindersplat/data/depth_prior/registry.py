"""Name -> depth-prior factory, for configs and the CLI (``make_depth_prior("simulated", seed=1)``)."""

from __future__ import annotations

from typing import Callable

from .adapters import DepthAnythingV2Adapter, ExportedDepthPrior, NetworkDepthPrior, UniK3DAdapter
from .base import MISSING_PRIOR_HELP, ConstantPrior, DepthPrior, GroundTruthPrior, MissingPrior, NoPrior
from .degraded import DegradedPrior
from .files import FilePrior
from .mixed import MixedPrior
from .simulated import SimulatedPrior

__all__ = ["DEPTH_PRIORS", "NETWORK_PRIORS", "register_depth_prior", "make_depth_prior", "parse_depth_prior",
           "parse_network_prior", "require_depth_prior"]

DEPTH_PRIORS: dict[str, Callable[..., DepthPrior]] = {}


def register_depth_prior(name: str, factory: Callable[..., DepthPrior]) -> None:
    """Register a factory under ``name`` (re-registering a name is an error)."""
    if name in DEPTH_PRIORS:
        raise ValueError(f"depth prior {name!r} is already registered")
    DEPTH_PRIORS[name] = factory


def make_depth_prior(name: str, /, **kwargs) -> DepthPrior:
    """Instantiate the prior registered as ``name`` with ``kwargs`` (``make_depth_prior("file", name="unik3d")``)."""
    if name not in DEPTH_PRIORS:
        hint = _EXPORT_HINT if name in ("depth_anywhere", "unifuse") else ""
        raise ValueError(f"unknown depth prior {name!r}; available: {sorted(DEPTH_PRIORS)}{hint}")
    return DEPTH_PRIORS[name](**kwargs)


_EXPORT_HINT = ("; Depth Anywhere and UniFuse have no package API to call: export the network once with "
                "torch.export.save where its code lives and give exported:NET.pt2 (docs/data.md)")


# The one positional argument a "name:value" spec fills in, per prior.
_SPEC_ARGUMENT = {"constant": ("depth", float), "file": ("name", str), "simulated": ("seed", int),
                  "degraded": ("kind", str), "mixed": ("parts", str),
                  "exported": ("weights", str), "unik3d": ("weights", str), "depth_anything_v2": ("weights", str)}

# Priors that run a depth network (what `cylindersplat data priors --net` accepts).
NETWORK_PRIORS = ("exported", "unik3d", "depth_anything_v2")


def parse_depth_prior(spec: str, **kwargs) -> DepthPrior:
    """A prior from a command-line spec: ``name`` or ``name:value`` (``constant:2.5``, ``exported:net.pt2``,
    ``unik3d:/models/unik3d-vitl``, ``depth_anything_v2:depth-anything/Depth-Anything-V2-Small-hf``,
    ``file:unik3d``, ``file:/priors/unik3d``, ``simulated:3`` (seed), ``simulated:blur_sigma=0.5,seed=3`` or
    ``degraded:mono`` / ``degraded:scale,seed=1``). ``kwargs`` go to the prior (e.g. ``device=`` of a network)."""
    name, sep, value = spec.partition(":")
    if name not in DEPTH_PRIORS:
        make_depth_prior(name)  # the unknown-name error
    if sep:
        if name not in _SPEC_ARGUMENT:
            raise ValueError(f"depth prior {name!r} takes no ':value' (spec {spec!r})")
        key, kind = _SPEC_ARGUMENT[name]
        try:
            if name == "simulated":  # simulated:SEED or simulated:key=value,...
                kwargs.update(SimulatedPrior.spec_arguments(value))
            elif name == "degraded":  # degraded:KIND or degraded:KIND,seed=N
                kwargs.update(DegradedPrior.spec_arguments(value))
            elif name == "mixed":  # mixed:A+B[,seed=N]
                kwargs.update(MixedPrior.spec_arguments(value))
            else:
                kwargs[key] = kind(value)
        except ValueError as error:
            own_message = str(error).startswith(("simulated prior:", "degraded prior:", "mixed prior:"))
            detail = str(error) if own_message else f"{value!r} is not a valid {key}"
            raise ValueError(f"depth prior spec {spec!r}: {detail}") from None
    elif name in NETWORK_PRIORS:
        raise FileNotFoundError(f"depth prior {name!r} needs its weights: write {name}:PATH (see docs/data.md)")
    if name not in NETWORK_PRIORS:
        kwargs.pop("device", None)  # only networks run on a device
    prior = make_depth_prior(name, **kwargs)
    prior._spec = spec
    return prior


def parse_network_prior(spec: str, **kwargs) -> NetworkDepthPrior:
    """:func:`parse_depth_prior` for specs that name a depth network (``exported:``, ``unik3d:``,
    ``depth_anything_v2:``)."""
    name = spec.partition(":")[0]
    if name not in DEPTH_PRIORS:
        make_depth_prior(name)  # the unknown-name error (with the export route for Depth Anywhere / UniFuse)
    if name not in NETWORK_PRIORS:
        raise ValueError(f"{spec!r} is not a depth network; give one of "
                         f"{', '.join(n + ':...' for n in NETWORK_PRIORS)} (e.g. exported:depth_net.pt2)")
    return parse_depth_prior(spec, **kwargs)


for _cls in (NoPrior, GroundTruthPrior, ConstantPrior, SimulatedPrior, DegradedPrior, MixedPrior, FilePrior,
             ExportedDepthPrior, UniK3DAdapter, DepthAnythingV2Adapter):
    register_depth_prior(_cls.name, _cls)


def require_depth_prior(dataset, option: str = "data.depth_prior") -> None:
    """Raise ``ValueError`` (one line, what to do) when ``dataset`` has no depth prior chosen (its default
    is :class:`MissingPrior`); an explicit ``none`` (:class:`NoPrior`) is the user's decision."""
    if isinstance(getattr(dataset, "depth_prior", None), MissingPrior):
        raise ValueError(MISSING_PRIOR_HELP.format(option=option))
