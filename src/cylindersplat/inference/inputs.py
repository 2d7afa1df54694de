"""A user's own panoramas: a folder of equirect images plus ``poses.json`` -> model inputs.

Format (see ``docs/inference.md``)::

    my_scene/
      poses.json
      pano_a.jpg                 # equirect, W == 2H, any size (resized to the model's input size)
      pano_a_depth.png           # optional depth prior: 16-bit, `depth_scale` units per metre, 0 = unknown
      pano_b.jpg                 #   (or a float .npy in metres)
      ...

``poses.json`` either lists frames explicitly::

    {"frames": [{"image": "pano_a.jpg", "c2w": [[r00, r01, r02, tx], ..., [0, 0, 0, 1]],
                 "depth": "pano_a_depth.png"}, ...],
     "depth_scale": 1000}

or gives only poses, matched to the folder's images in name order::

    {"poses": [[[...4x4...]], ...]}

Poses are OpenCV camera-to-world (+x right, +y down, +z forward; 3x4 or 4x4) in metres, unless
``"convention"`` says ``opengl_c2w``/``blender_c2w`` (+y up, +z back), ``opencv_w2c`` or ``opengl_w2c``. Every
problem (missing/corrupt file, non-2:1 image, count mismatch, non-finite or non-rigid pose, depth
of the wrong size) raises an error naming the file.

A folder with a nerfstudio ``transforms.json`` (``"camera_model": "EQUIRECTANGULAR"``) instead of
``poses.json`` is read as well (:mod:`.pose_formats`).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import torch
from jaxtyping import Float
from torch import Tensor

from ..data.depth_prior import DepthPrior, NoPrior, PriorQuery
from ..data.io import DEPTH_PNG_SCALE, open_image, read_depth_npy, read_depth_png, read_rgb
from ..geometry import validate_c2w
from .pose_formats import is_transforms_json, read_transforms_json

__all__ = ["PanoramaInputs", "load_panorama_folder", "write_panorama_folder", "read_poses_file", "list_panoramas",
           "IMAGE_SUFFIXES"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".webp", ".bmp", ".tif", ".tiff")
POSES_FILE = "poses.json"
TRANSFORMS_FILE = "transforms.json"  # nerfstudio's format, read when a folder has no poses.json


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


def _all_numbers(value) -> bool:
    """Nested lists of JSON numbers only (no strings, booleans or nulls, which torch would convert or choke on)."""
    if isinstance(value, list):
        return all(_all_numbers(v) for v in value)
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _parse_pose(value, where: str, convention: str = "opencv_c2w") -> Tensor:
    if not isinstance(value, list) or not _all_numbers(value):
        raise ValueError(f"{where}: pose must be a 3x4 or 4x4 list of numbers, got {value!r:.80}")
    try:
        pose = torch.tensor(value, dtype=torch.float64)
    except (TypeError, ValueError) as exc:  # ragged rows
        raise ValueError(f"{where}: pose must be a 3x4 or 4x4 list of numbers ({exc})") from None
    if pose.shape == (3, 4):
        pose = torch.cat((pose, torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=pose.dtype)))
    if pose.shape != (4, 4):
        raise ValueError(f"{where}: pose must be 3x4 or 4x4, got shape {tuple(pose.shape)}")
    validate_c2w(pose, name=where)  # finite, orthonormal rotation (det +1), last row 0 0 0 1
    return _to_opencv_c2w(pose, convention).float()


# Pose conventions a poses file may declare ("convention"), each mapped to OpenCV camera-to-world.
_GL_TO_CV = torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=torch.float64))  # +y up, +z back -> +y down, +z forward
POSE_CONVENTIONS = ("opencv_c2w", "opengl_c2w", "blender_c2w", "opencv_w2c", "opengl_w2c")


def _to_opencv_c2w(pose: Tensor, convention: str) -> Tensor:
    if convention.endswith("_w2c"):
        rot, t = pose[:3, :3], pose[:3, 3]
        pose = torch.eye(4, dtype=pose.dtype)
        pose[:3, :3], pose[:3, 3] = rot.T, -rot.T @ t
    if convention.startswith(("opengl", "blender")):
        pose = pose @ _GL_TO_CV.to(pose.dtype)
    return pose


def read_poses_file(path: str | Path) -> list[tuple[str | None, Tensor, str | None]]:
    """``[(image name or None, c2w (4, 4), depth file or None), ...]`` from a poses file.

    ``"convention"`` (default ``"opencv_c2w"``) says how the file's matrices are meant:
    OpenCV (+x right, +y down, +z forward) or OpenGL/Blender (+x right, +y up, +z back) cameras,
    camera-to-world (``_c2w``) or world-to-camera (``_w2c``); all are returned as OpenCV c2w. A nerfstudio
    ``transforms.json`` of ``EQUIRECTANGULAR`` frames is read too (file names relative to its folder).
    """
    return _read_entries(path)[0]


def _read_entries(path: str | Path) -> tuple[list[tuple[str | None, Tensor, str | None]], bool]:
    """:func:`read_poses_file`'s entries and whether the file is a nerfstudio ``transforms.json`` (whose file
    names are relative to its own folder and whose ``.npy`` depths are in ``depth_scale`` units too)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"missing poses file: {path}")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None
    if is_transforms_json(data):  # nerfstudio: OpenGL c2w of EQUIRECTANGULAR frames
        return [(r.image, r.c2w.float(), r.depth) for r in read_transforms_json(path, data=data)], True
    if isinstance(data, list):
        data = {"poses": data}
    if not isinstance(data, dict) or not ({"frames", "poses"} & set(data)):
        raise ValueError(f'{path}: expected {{"frames": [...]}} or {{"poses": [...]}} (see docs/inference.md)')
    convention = data.get("convention", "opencv_c2w")
    if convention not in POSE_CONVENTIONS:
        raise ValueError(f"{path}: unknown pose convention {convention!r}; use one of {list(POSE_CONVENTIONS)}")
    key = "frames" if "frames" in data else "poses"
    if not isinstance(data[key], list):
        raise ValueError(f'{path}: "{key}" must be a list, got {type(data[key]).__name__}')
    entries = []
    if key == "frames":
        for i, frame in enumerate(data["frames"]):
            where = f"{path} frame {i}"
            if not isinstance(frame, dict) or "c2w" not in frame:
                raise ValueError(f'{where}: each frame needs "c2w" (and "image" for input folders)')
            for name in ("image", "depth"):
                if frame.get(name) is not None and not isinstance(frame[name], str):
                    raise ValueError(f'{where}: "{name}" must be a file name, got {frame[name]!r}')
            entries.append((frame.get("image"), _parse_pose(frame["c2w"], where, convention), frame.get("depth")))
    else:
        entries = [(None, _parse_pose(p, f"{path} pose {i}", convention), None) for i, p in enumerate(data["poses"])]
    if not entries:
        raise ValueError(f"{path}: no poses")
    return entries, False


def _depth_scale(path: Path) -> float:
    data = json.loads(path.read_text())
    scale = data.get("depth_scale", DEPTH_PNG_SCALE) if isinstance(data, dict) else DEPTH_PNG_SCALE
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not math.isfinite(scale) or scale <= 0:
        raise ValueError(f"{path}: depth_scale must be a positive number, got {scale!r}")
    return float(scale)


def _folder_images(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and not p.stem.endswith("_depth"))


def _find_depth(image: Path) -> Path | None:
    for suffix in (".png", ".npy"):
        candidate = image.with_name(f"{image.stem}_depth{suffix}")
        if candidate.is_file():
            return candidate
    return None


def _folder_entries(folder: Path, poses_path: Path) -> list[tuple[str, Tensor, str | None]]:
    """``[(image name, c2w, depth file or None)]`` of an input folder (poses matched to images if unnamed)."""
    entries, nerfstudio = _read_entries(poses_path)
    if nerfstudio and poses_path.parent.resolve() != folder.resolve():  # its names are relative to its own folder
        entries = [(_rebase(name, poses_path.parent, folder), pose, depth and _rebase(depth, poses_path.parent, folder))
                   for name, pose, depth in entries]
    if all(name is None for name, _, _ in entries):
        images = _folder_images(folder)
        if len(images) != len(entries):
            listed = ", ".join(p.name for p in images) or "none"
            raise ValueError(
                f"{poses_path} has {len(entries)} poses but {folder} has {len(images)} panoramas ({listed}); "
                'give one pose per image (matched in name order) or list "frames" with "image" names'
            )
        entries = [(p.name, pose, None) for p, (_, pose, _) in zip(images, entries)]
    elif any(name is None for name, _, _ in entries):
        raise ValueError(f'{poses_path}: every frame needs an "image" name')
    return entries


def _rebase(name: str, base: Path, folder: Path) -> str:
    return os.path.relpath((base / name).resolve(), folder.resolve())


def _poses_path(folder: Path, poses_file: str | Path | None) -> Path:
    """The poses file: ``poses_file`` if given, else ``poses.json``, else a nerfstudio ``transforms.json``."""
    if poses_file is not None:
        return Path(poses_file)
    if not (folder / POSES_FILE).is_file() and (folder / TRANSFORMS_FILE).is_file():
        return folder / TRANSFORMS_FILE
    if not (folder / POSES_FILE).is_file():
        raise FileNotFoundError(f"missing poses file: {folder / POSES_FILE} (or a nerfstudio {TRANSFORMS_FILE}; "
                                "see docs/inference.md)")
    return folder / POSES_FILE


def list_panoramas(folder: str | Path, poses_file: str | Path | None = None) -> list[Path]:
    """The panoramas of an input folder, in the order of its poses file."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"input folder not found: {folder}")
    poses_path = _poses_path(folder, poses_file)
    return [folder / name for name, _, _ in _folder_entries(folder, poses_path)]


def _check_depth(depth: Tensor, source: str, depth_prior: DepthPrior | None) -> None:
    """No silent zeros: a frame's depth without one positive pixel is refused unless the prior is ``none``."""
    if isinstance(depth_prior, NoPrior) or bool((depth > 0).any()):
        return
    raise ValueError(f"{source} has no positive depth (all zeros = unknown): the model would get no depth; fix it, or "
                     "pass --depth-prior none to really run without depth")


def load_panorama_folder(
    folder: str | Path,
    resolution: tuple[int, int],
    depth_prior: DepthPrior | None = None,
    poses_file: str | Path | None = None,
) -> PanoramaInputs:
    """Read the panoramas, poses and depth priors of ``folder`` at ``resolution`` ``(H, W)``.

    The depth prior of a frame is its depth file (``"depth"`` in ``poses.json``, else
    ``<image stem>_depth.png|.npy``); frames without one get ``depth_prior(query)`` when a prior is
    given (e.g. a depth foundation model, or ``file:NAME`` for ``FOLDER/priors/NAME/<stem>.png`` from
    ``cylindersplat data priors``) and are an error otherwise. A depth without a single positive
    pixel is an error unless ``depth_prior`` is :class:`NoPrior` (asked for by name).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"input folder not found: {folder}")
    poses_path = _poses_path(folder, poses_file)
    entries = _folder_entries(folder, poses_path)
    scale = _depth_scale(poses_path)
    npy_in_depth_units = _read_entries(poses_path)[1]  # nerfstudio keeps .npy depth in the units of its PNGs
    h, w = resolution
    rgbs, depths, poses, names, missing = [], [], [], [], []
    for name, pose, depth_name in entries:
        image_path = folder / name
        rgb = read_rgb(image_path, size=(h, w))
        depth_path = folder / depth_name if depth_name else _find_depth(image_path)
        if depth_path is not None:
            if depth_path.suffix.lower() == ".npy":
                depth = read_depth_npy(depth_path, size=(h, w))
                if npy_in_depth_units:
                    depth = depth / scale
            else:
                open_image(depth_path)  # clear error when missing/corrupt
                depth = read_depth_png(depth_path, size=(h, w), scale=scale)
            _check_depth(depth, f"depth file {depth_path}", depth_prior)
        elif depth_prior is not None:
            depth = depth_prior(PriorQuery(image=rgb, gt_depth=None, rgb_path=image_path, key=f"input/{image_path.stem}",
                                           dataset_root=folder))
            if tuple(depth.shape) != (h, w):
                raise ValueError(f"depth prior {depth_prior.name!r} returned {tuple(depth.shape)} for {image_path}, expected {(h, w)}")
            _check_depth(depth, f"depth prior {depth_prior.spec!r} of {image_path}", depth_prior)
        else:
            missing.append(name)
            depth = None
        rgbs.append(rgb)
        depths.append(depth)
        poses.append(pose)
        names.append(name)
    if missing:
        raise FileNotFoundError(
            f"no depth prior for {', '.join(missing)} in {folder}: add <image stem>_depth.png (16-bit, "
            f"{scale:g} per metre) or .npy (metres), or choose --depth-prior (e.g. constant:2.0 or exported:depth_net.pt2)"
        )
    return PanoramaInputs(torch.stack(rgbs), torch.stack(depths).float(), torch.stack(poses), names)


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
    (folder / POSES_FILE).write_text(json.dumps({"convention": "opencv_c2w", "depth_scale": DEPTH_PNG_SCALE, "frames": frames}, indent=1))
    return folder
