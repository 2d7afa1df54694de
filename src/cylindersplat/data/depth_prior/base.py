"""Depth-prior interface: what a loader asks for each context view."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch
from jaxtyping import Float
from torch import Tensor

__all__ = ["PriorQuery", "DepthPrior", "NoPrior", "MissingPrior", "GroundTruthPrior", "ConstantPrior",
           "StoredDepthPrior", "MISSING_PRIOR_HELP"]


@dataclass
class PriorQuery:
    """Everything a prior may use for one view.

    ``image`` ``(3, H, W)`` at the loader's output resolution; ``gt_depth`` ``(H, W)`` or ``None``;
    ``rgb_path`` the stored panorama (file priors look next to it); ``key`` a stable id
    ``"{dataset}/{scene}/{frame}"`` (seeds the simulated prior); ``dataset_root`` the folder the
    dataset was opened at (file priors find ``<dataset_root>/priors/<name>/...`` relative to it);
    ``depth_path`` the file ``gt_depth`` was read from, if any.
    """

    image: Float[Tensor, "3 H W"]
    gt_depth: Float[Tensor, "H W"] | None
    rgb_path: Path | None
    key: str
    dataset_root: Path | None = None
    depth_path: Path | None = None

    @property
    def size(self) -> tuple[int, int]:
        return tuple(self.image.shape[-2:])


class DepthPrior:
    """A source of per-view radial depth priors ``(H, W)`` in metres (0 = unknown)."""

    name = "base"
    allows_zeros = False  # an all-zero prior is an error (no silent zeros), except for the prior `none`

    @property
    def spec(self) -> str:
        """The spec that asks for this prior (``parse_depth_prior``), for messages and records."""
        return getattr(self, "_spec", self.name)

    def source(self, query: PriorQuery) -> str:
        """Where this prior's depth of one view comes from, for messages."""
        return f"depth prior {self.spec!r} of {query.rgb_path if query.rgb_path is not None else query.key}"

    def __call__(self, query: PriorQuery) -> Float[Tensor, "H W"]:
        raise NotImplementedError


class NoPrior(DepthPrior):
    """All-zero prior (no depth information): only ever used when asked for by name (``none``)."""

    name = "none"
    allows_zeros = True

    def __call__(self, query: PriorQuery) -> Tensor:
        return torch.zeros(query.size)


MISSING_PRIOR_HELP = ("the model needs a depth prior for every input view and this dataset has none of its own; "
                      "choose one: {option}=file:NAME (files written by `cylindersplat data priors --name NAME`), "
                      "{option}=unik3d:WEIGHTS_DIR, {option}=exported:NET.pt2, {option}=gt (ground truth, an oracle), "
                      "{option}=constant:METRES, or {option}=none to really run without one")


class MissingPrior(DepthPrior):
    """The default of datasets without a depth prior of their own (PanoGRF layout, 360Loc): asking it for
    depth is an error that says how to choose one (there is no silent all-zero default)."""

    name = "unset"

    def __init__(self, option: str = "depth_prior") -> None:
        self.option = option

    def __call__(self, query: PriorQuery) -> Tensor:
        raise ValueError(f"{query.key}: " + MISSING_PRIOR_HELP.format(option=self.option))


class GroundTruthPrior(DepthPrior):
    """Oracle prior: the ground-truth depth itself (for ablations / upper bounds)."""

    name = "gt"

    def __call__(self, query: PriorQuery) -> Tensor:
        if query.gt_depth is None:
            raise ValueError(f"{query.key}: the 'gt' depth prior needs ground-truth depth, which this view lacks")
        return query.gt_depth.clone()


class ConstantPrior(DepthPrior):
    """Every pixel at ``depth`` metres (a sphere around the camera): a last resort for inputs with no depth."""

    name = "constant"

    def __init__(self, depth: float = 2.0) -> None:
        from ...validation import check_constant_depth

        self.depth = check_constant_depth(depth)  # 1 cm to 1 km: beyond is a unit mistake

    def __call__(self, query: PriorQuery) -> Tensor:
        return torch.full(query.size, self.depth)


class StoredDepthPrior(DepthPrior):
    """A view's own stored depth where it has one (``PriorQuery.gt_depth``: e.g. the ``<stem>_depth.png``
    of an input folder, docs/inference.md), else ``fallback`` (default :class:`MissingPrior`: an error).

    This is how a folder of posed panoramas gives its depth files to the model as priors while frames
    without one get a chosen prior (``--depth-prior``). Zeros are allowed where ``fallback`` allows them
    (the prior ``none``).
    """

    name = "stored"

    def __init__(self, fallback: DepthPrior | None = None) -> None:
        self.fallback = fallback if fallback is not None else MissingPrior()

    @property
    def spec(self) -> str:
        if isinstance(self.fallback, MissingPrior):
            return "depth files"
        return f"depth files, else {self.fallback.spec}"

    @property
    def allows_zeros(self) -> bool:
        return self.fallback.allows_zeros

    def source(self, query: PriorQuery) -> str:
        if query.gt_depth is not None:
            return f"depth file {query.depth_path if query.depth_path is not None else query.key}"
        return self.fallback.source(query)

    def __call__(self, query: PriorQuery) -> Tensor:
        if query.gt_depth is not None:
            return query.gt_depth.clone()
        return self.fallback(query)
