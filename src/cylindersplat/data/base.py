"""Shared machinery of every panorama dataset: frame references -> :class:`Sample`.

A concrete dataset only lists its examples (:meth:`PanoramaDataset.__len__`,
:meth:`PanoramaDataset.example`) as :class:`ExampleRef`: frame files, poses and the context/target
split. Loading, resizing, validity checks, depth priors and metadata are done here once.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import Tensor
from torch.utils.data import Dataset

from ..errors import InputError
from ..geometry import validate_c2w
from ..validation import check_depth_plausible, check_translation_plausible
from .depth_prior.base import DepthPrior, MissingPrior, PriorQuery
from .io import read_depth_npy, read_depth_png, read_rgb
from .sample import Sample
from .views import ViewSplit

__all__ = ["FrameRef", "ExampleRef", "PanoramaDataset", "DATASET_OVERRIDE"]

DATASET_OVERRIDE = "data.check_plausibility=false in train, or check_plausibility=False on the dataset in Python"


@dataclass
class FrameRef:
    """One stored panorama: its files and OpenCV ``c2w`` (4x4, float32).

    ``depth``: its stored radial depth, a 16-bit PNG or a float ``.npy``; ``depth_scale``: the file's units
    per metre (``None``: the format's own, millimetres for PNG, metres for ``.npy``).
    """

    name: str
    rgb: Path
    c2w: Tensor
    depth: Path | None = None
    depth_scale: float | None = None


@dataclass
class ExampleRef:
    """One example: the frames it needs and which are context/target."""

    scene: str
    frames: list[FrameRef]
    views: ViewSplit
    metadata: dict[str, Any] = field(default_factory=dict)


class PanoramaDataset(Dataset):
    """Base class. ``resolution`` (H, W) resizes on load (None = stored size); ``stored_size``
    (H, W), when a layout fixes it, is checked against every file; ``depth_prior`` fills
    ``Sample.context_priors`` (default: :class:`MissingPrior`, an error asking for a choice; a
    context prior without a single positive pixel is an error unless the prior is ``none``).

    ``target_reference`` (a :class:`DepthPrior`, default ``None``) fills
    ``Sample.target_reference_depths``: the reference depth of the target views (the depth loss's
    ``D_ref``, or the evaluation's PCC reference). ``data_root`` is the folder the dataset was opened
    at; file priors resolve ``<data_root>/priors/<name>/...`` against it.

    Every frame a sample loads is checked once, cheaply (a median per depth map), and a corrupt or absurd one
    stops with one line naming its file (:meth:`check_frame`): a non-finite or non-rigid pose, a depth file
    without a single positive pixel (unless the prior allows zeros: ``none``), and (unless ``check_plausibility``
    is False) a camera beyond 10 km or a depth file whose median lies outside 1 cm to 1 km
    (:mod:`cylindersplat.validation`).
    """

    dataset_name = "base"
    data_root: Path | None = None
    target_reference: DepthPrior | None = None
    check_plausibility: bool = True  # the bounds of check_frame (train: data.check_plausibility)
    #: how the bounds' error says to skip them (the folder reader of render/export names its CLI option)
    plausibility_override: str = DATASET_OVERRIDE

    def __init__(
        self,
        resolution: tuple[int, int] | None = None,
        depth_prior: DepthPrior | None = None,
        stored_size: tuple[int, int] | None = None,
        depth_resize: str = "area",
    ) -> None:
        if resolution is not None and resolution[1] != 2 * resolution[0]:
            raise ValueError(f"resolution must be (H, W) with W == 2H, got {resolution}")
        self.resolution = tuple(resolution) if resolution is not None else None
        self.depth_prior = depth_prior or MissingPrior()
        self.stored_size = stored_size
        self.depth_resize = depth_resize

    # -- to implement ------------------------------------------------------------------------------
    def __len__(self) -> int:
        raise NotImplementedError

    def example(self, index: int) -> ExampleRef:
        raise NotImplementedError

    def frames(self) -> list[tuple[FrameRef, str]]:
        """Every stored panorama the dataset uses, once, with its prior key ``"{dataset}/{scene}/{frame}"``."""
        seen: dict[Path, tuple[FrameRef, str]] = {}
        for index in range(len(self)):
            ref = self.example(index)
            for frame in ref.frames:
                seen.setdefault(Path(frame.rgb), (frame, f"{self.dataset_name}/{ref.scene}/{frame.name}"))
        return list(seen.values())

    # -- shared loading ----------------------------------------------------------------------------
    def load_frame(self, frame: FrameRef) -> tuple[Tensor, Tensor | None]:
        """One stored panorama at the dataset's resolution: ``(rgb (3, H, W) in [0, 1], depth (H, W) in metres or
        None)``."""
        image = read_rgb(frame.rgb, size=self.resolution, expected=self.stored_size)
        return image, self._read_depth(frame, tuple(image.shape[-2:]))

    def _read_depth(self, frame: FrameRef, size: tuple[int, int] | None) -> Tensor | None:
        """A frame's stored depth in metres, resized to ``size`` (None: as stored), or None without a file."""
        if frame.depth is None:
            return None
        expected = self.stored_depth_size(frame)
        if Path(frame.depth).suffix.lower() == ".npy":
            depth = read_depth_npy(frame.depth, size=size, resize_mode=self.depth_resize, expected=expected)
            return depth if frame.depth_scale is None else depth / frame.depth_scale
        return read_depth_png(frame.depth, size=size, expected=expected, resize_mode=self.depth_resize,
                              **({} if frame.depth_scale is None else {"scale": frame.depth_scale}))

    def check_frame(self, frame: FrameRef, depth: Tensor | None) -> None:
        """One loaded frame (``depth``: its stored depth in metres, or None) is usable, else a one-line
        :class:`~cylindersplat.errors.InputError` naming its file (see the class docstring)."""
        try:
            validate_c2w(frame.c2w, name=f"pose of {frame.rgb}")
        except ValueError as exc:
            raise InputError(f"{exc}; fix the dataset's pose of this frame (OpenCV camera-to-world, metres)") from None
        if self.check_plausibility:
            check_translation_plausible(frame.c2w, f"pose of {frame.rgb}")
        if depth is None:
            return
        # an empty or corrupt file says nothing as reference or prior (unless no depth was asked for: prior none)
        if not self.depth_prior.allows_zeros and not float(depth.max()) > 0:  # stored depths are >= 0
            raise InputError(f"depth file {frame.depth} has no positive depth (all zeros = unknown): the file is empty "
                             "or corrupt; write it again or remove the frame")
        if self.check_plausibility:
            check_depth_plausible(depth, str(frame.depth), self.plausibility_override)

    def stored_depth_size(self, frame: FrameRef) -> tuple[int, int] | None:
        """(H, W) a frame's depth file must have (None: any 2:1 size); the layout's size by default."""
        return self.stored_size

    def stored_depths(self, index: int) -> tuple[Tensor | None, Tensor | None]:
        """Ground-truth depth of example ``index`` at the stored resolution: ``(targets (T, Hs, Ws), contexts
        (V, Hs, Ws))``, each None where a frame has no depth. The occluded-pixel masks are decided on these
        (:func:`~cylindersplat.data.occlusion.occluded_mask`), whatever the evaluation resolution."""
        ref = self.example(index)

        def stack(indices):
            depths = [self._read_depth(ref.frames[i], None) for i in indices]
            if not depths or any(d is None for d in depths) or len({tuple(d.shape) for d in depths}) > 1:
                return None
            return torch.stack(depths)

        return stack(ref.views.target), stack(ref.views.context)

    def __getitem__(self, index: int) -> Sample:
        if not 0 <= index < len(self):
            raise IndexError(f"{type(self).__name__} index {index} out of range (len {len(self)})")
        ref = self.example(index)
        needed = sorted(set(ref.views.context) | set(ref.views.target))
        loaded = {i: self.load_frame(ref.frames[i]) for i in needed}
        sizes = {tuple(loaded[i][0].shape) for i in needed}
        if len(sizes) > 1:
            files = ", ".join(str(ref.frames[i].rgb) for i in needed)
            raise ValueError(f"frames of one example differ in size {sorted(sizes)}: {files}")
        for i in needed:
            self.check_frame(ref.frames[i], loaded[i][1])

        def stack_depths(indices):
            depths = [loaded[i][1] for i in indices]
            return None if not depths or any(d is None for d in depths) else torch.stack(depths)

        ctx, tgt = ref.views.context, ref.views.target
        h, w = next(iter(sizes))[-2:]

        def query(i):
            return PriorQuery(loaded[i][0], loaded[i][1], ref.frames[i].rgb,
                              f"{self.dataset_name}/{ref.scene}/{ref.frames[i].name}", self.data_root,
                              depth_path=ref.frames[i].depth)

        priors = []
        for i in ctx:
            q = query(i)
            prior = self.depth_prior(q).float()
            if tuple(prior.shape) != (h, w):
                raise ValueError(f"{self.depth_prior.source(q)} has shape {tuple(prior.shape)}, expected {(h, w)}")
            if not self.depth_prior.allows_zeros and not bool((prior > 0).any()):  # zeros only when asked for by name
                raise ValueError(
                    f"{self.depth_prior.source(q)} has no positive depth (all zeros = unknown): the model would get no "
                    "depth; check the files or the prior's network, or choose the prior none explicitly")
            priors.append(prior)
        references = None
        if self.target_reference is not None and tgt:
            references = torch.stack([self.target_reference(query(i)).float() for i in tgt])
        poses = torch.stack([f.c2w.float() for f in ref.frames])
        metadata = {
            "dataset": self.dataset_name,
            "scene": ref.scene,
            "baseline": _baseline(poses[list(ctx)], poses[list(tgt)]),
            "context_indices": list(ctx),
            "target_indices": list(tgt),
            "frame_names": [ref.frames[i].name for i in needed],
            "depth_prior": self.depth_prior.spec,
            **ref.metadata,
        }
        return Sample(
            context_images=torch.stack([loaded[i][0] for i in ctx]),
            context_priors=torch.stack(priors),
            context_poses=poses[list(ctx)],
            target_images=torch.stack([loaded[i][0] for i in tgt]) if tgt else torch.zeros(0, 3, h, w),
            target_depths=stack_depths(tgt),
            target_poses=poses[list(tgt)],
            metadata=metadata,
            context_gt_depths=stack_depths(ctx),
            target_reference_depths=references,
        )


def _baseline(context_poses: Tensor, target_poses: Tensor) -> float:
    """Largest distance between two context centres (one context: to the farthest target)."""
    centers = context_poses[:, :3, 3]
    if len(centers) == 1:
        centers = torch.cat([centers, target_poses[:, :3, 3]])
    return float(torch.cdist(centers.double(), centers.double()).max())
