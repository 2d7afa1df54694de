"""A user's own panoramas: a folder of equirect images plus ``poses.json`` -> model inputs.

The folder format (images, poses in several conventions or a nerfstudio ``transforms.json``, depth files)
is read by :class:`cylindersplat.data.FolderDataset` (:mod:`cylindersplat.data.folder`, ``docs/inference.md``),
the same loader ``eval --format folder`` and ``train data.format=folder`` use; :func:`load_panorama_folder`
is that dataset with every frame as an input view.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from jaxtyping import Float
from torch import Tensor

from ..data.depth_prior import DepthPrior
from ..data.folder import (
    IMAGE_SUFFIXES,
    POSE_CONVENTIONS,
    POSES_FILE,
    TRANSFORMS_FILE,
    FolderDataset,
    list_panoramas,
    poses_path,
    read_poses_file,
)
from ..data.io import DEPTH_PNG_SCALE
from ..data.poses.poses_json import warn_if_not_metric
from ..utils.atomic import atomic_write_text
from ..validation import PLAUSIBILITY_OVERRIDE, check_depth_plausible, check_scene_scale

__all__ = ["PanoramaInputs", "load_panorama_folder", "write_panorama_folder", "read_poses_file", "list_panoramas",
           "IMAGE_SUFFIXES", "POSE_CONVENTIONS", "POSES_FILE", "TRANSFORMS_FILE"]


@dataclass
class PanoramaInputs:
    """Context views of one reconstruction: images ``(V, 3, H, W)``, depth prior ``(V, H, W)``, c2w ``(V, 4, 4)``."""

    images: Float[Tensor, "V 3 H W"]
    depths: Float[Tensor, "V H W"]
    c2w: Float[Tensor, "V 4 4"]
    names: list[str] = field(default_factory=list)

    @property
    def size(self) -> tuple[int, int]:
        return tuple(self.images.shape[-2:])


def load_panorama_folder(
    folder: str | Path,
    resolution: tuple[int, int],
    depth_prior: DepthPrior | None = None,
    poses_file: str | Path | None = None,
    allow_outside_paths: bool = False,
    check_plausibility: bool = True,
) -> PanoramaInputs:
    """Read the panoramas, poses and depth priors of ``folder`` at ``resolution`` ``(H, W)``.

    The depth prior of a frame is its depth file (``"depth"`` in ``poses.json``, else
    ``<image stem>_depth.png|.npy``); frames without one get ``depth_prior(query)`` when a prior is
    given (e.g. a depth foundation model, or ``file:NAME`` for ``FOLDER/priors/NAME/<stem>.png`` from
    ``cylindersplat data priors``) and are an error otherwise. A depth without a single positive
    pixel is an error unless ``depth_prior`` is :class:`~cylindersplat.data.depth_prior.NoPrior` (asked for
    by name). This is :class:`~cylindersplat.data.FolderDataset` (``views="all_inputs"``), its one example;
    files named by the poses file must lie inside ``folder`` unless ``allow_outside_paths``. With
    ``check_plausibility`` each frame's depth (file or prior) must have a median within 1 cm to 1 km
    (:func:`cylindersplat.validation.check_depth_plausible`; the error names the file), and a scene whose size
    suggests a unit mistake (median depth beyond 100 m or below 5 cm, cameras spaced out of proportion with
    the depth) is warned about (:func:`cylindersplat.validation.check_scene_scale`, naming the folder).
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"input {folder} is a file, not a folder: give the folder that holds the panoramas and "
                         f"their poses file (here perhaps {folder.parent})")
    if not folder.is_dir():
        raise FileNotFoundError(f"input folder not found: {folder}")
    # One folder of panoramas, not a folder of them: its poses file must be there (and say metres: a warning if not).
    warn_if_not_metric(poses_path(folder, poses_file))
    dataset = FolderDataset(folder, resolution=resolution, depth_prior=depth_prior, poses_file=poses_file,
                            allow_outside_paths=allow_outside_paths, check_plausibility=check_plausibility)
    dataset.plausibility_override = PLAUSIBILITY_OVERRIDE  # the depth files' bounds are checked on loading
    dataset.check_depth("--depth-prior")
    sample = dataset[0]
    frames = [dataset.example(0).frames[i] for i in sample.metadata["context_indices"]]
    names = [frame.name for frame in frames]
    if check_plausibility:
        for frame, depth in zip(frames, sample.context_priors):
            if frame.depth is None:  # a network's (or constant) prior, not checked as a file
                check_depth_plausible(depth, f"the depth prior of {frame.name}")
        check_scene_scale(sample.context_priors, sample.context_poses, str(folder))
    return PanoramaInputs(sample.context_images, sample.context_priors, sample.context_poses, names)


def write_panorama_folder(
    folder: str | Path,
    images: Float[Tensor, "V 3 H W"],
    c2w: Float[Tensor, "V 4 4"],
    depths: Float[Tensor, "V H W"] | None = None,
    names: list[str] | None = None,
) -> Path:
    """Write panoramas (PNG), optional depth priors (16-bit mm PNG) and ``poses.json`` in the input format."""
    from ..data.io import write_depth_png, write_rgb

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    names = names or [f"pano_{i:02d}" for i in range(len(images))]
    frames = []
    for i, name in enumerate(names):
        write_rgb(folder / f"{name}.png", images[i])
        frame = {"image": f"{name}.png", "c2w": c2w[i].tolist()}
        if depths is not None:
            write_depth_png(folder / f"{name}_depth.png", depths[i])
            frame["depth"] = f"{name}_depth.png"
        frames.append(frame)
    atomic_write_text(folder / POSES_FILE, json.dumps({"convention": "opencv_c2w", "depth_scale": DEPTH_PNG_SCALE,
                                                      "frames": frames}, indent=1))
    return folder
