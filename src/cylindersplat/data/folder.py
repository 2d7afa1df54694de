"""A user's folder of posed panoramas (the input format of ``docs/inference.md``) as a dataset.

Format::

    my_scene/
      poses.json
      pano_a.jpg                 # equirect, W == 2H, any size (resized to the model's input size)
      pano_a_depth.png           # optional depth: 16-bit, `depth_scale` units per metre, 0 = unknown
      pano_b.jpg                 #   (or a float .npy in metres)
      ...

``poses.json`` either lists frames explicitly::

    {"frames": [{"image": "pano_a.jpg", "c2w": [[r00, r01, r02, tx], ..., [0, 0, 0, 1]],
                 "depth": "pano_a_depth.png"}, ...],
     "depth_scale": 1000}

or gives only poses, matched to the folder's images in name order::

    {"poses": [[[...4x4...]], ...]}

Poses are OpenCV camera-to-world (+x right, +y down, +z forward; 3x4 or 4x4) in metres, unless
``"convention"`` says ``opengl_c2w``/``blender_c2w`` (+y up, +z back), ``opencv_w2c`` or ``opengl_w2c``. A folder
with a nerfstudio ``transforms.json`` (``"camera_model": "EQUIRECTANGULAR"``) instead of ``poses.json`` is read
as well (:mod:`cylindersplat.data.poses`, which owns every pose convention). Every problem (missing/corrupt file,
non-2:1 image, count mismatch, non-finite or non-rigid pose, depth of the wrong size) raises an error naming the
file.

:class:`FolderDataset` reads such folders through the machinery every dataset shares
(:class:`~cylindersplat.data.base.PanoramaDataset`): ``render``/``export``/``view`` (through
:func:`cylindersplat.inference.load_panorama_folder`), ``eval --format folder`` and ``train data.format=folder``
take the same path from files to the model. A frame's depth file is its input prior (its *stored depth*,
handed on by :class:`~cylindersplat.data.depth_prior.StoredDepthPrior`); frames without one get the chosen
prior (``--depth-prior``), and with no prior chosen they are an error.
"""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path
from typing import Sequence

from torch import Tensor

from ..utils.jsonfile import read_json_file
from ..utils.notices import Notice
from ..validation import check_translation_plausible
from .base import ExampleRef, FrameRef, PanoramaDataset
from .confine import confined_path
from .depth_prior.base import DepthPrior, MissingPrior, StoredDepthPrior
from .depth_prior.files import PRIORS_DIR
from .io import DEPTH_PNG_SCALE
from .poses import POSE_CONVENTIONS, is_transforms_json, parse_pose_matrix, read_transforms_json, to_opencv_c2w
from .repeated_frames import repeated_frames
from .views import ViewSplit, select_views

__all__ = ["FolderDataset", "FOLDER_VIEWS", "IMAGE_SUFFIXES", "POSES_FILE", "TRANSFORMS_FILE", "POSE_CONVENTIONS",
           "read_poses_file", "list_panoramas", "input_files", "is_input_folder", "poses_path"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".webp", ".bmp", ".tif", ".tiff")
POSES_FILE = "poses.json"
TRANSFORMS_FILE = "transforms.json"  # nerfstudio's format, read when a folder has no poses.json

# Views of a folder: every frame an input (no target), the frames named by `targets` held out, or a protocol.
FOLDER_VIEWS = ("all_inputs", "held_out", "two_view", "one_view", "n_view")


# --- the poses file ---------------------------------------------------------------------------------------


def _parse_pose(value, where: str, convention: str = "opencv_c2w") -> Tensor:
    """One pose of a poses file as OpenCV c2w (float32); the conversion is :mod:`.poses.conventions`'."""
    return to_opencv_c2w(parse_pose_matrix(value, where), convention).float()


def read_poses_file(path: str | Path) -> list[tuple[str | None, Tensor, str | None]]:
    """``[(image name or None, c2w (4, 4), depth file or None), ...]`` from a poses file.

    ``"convention"`` (default ``"opencv_c2w"``) says how the file's matrices are meant:
    OpenCV (+x right, +y down, +z forward) or OpenGL/Blender (+x right, +y up, +z back) cameras,
    camera-to-world (``_c2w``) or world-to-camera (``_w2c``); all are returned as OpenCV c2w. A nerfstudio
    ``transforms.json`` of ``EQUIRECTANGULAR`` frames is read too (file names relative to its folder).
    """
    return _read_poses(path)[0]


def _read_poses(path: str | Path) -> tuple[list[tuple[str | None, Tensor, str | None]], bool, float]:
    """:func:`read_poses_file`'s entries, whether the file is a nerfstudio ``transforms.json`` (whose file
    names are relative to its own folder and whose ``.npy`` depths are in ``depth_scale`` units too), and
    its ``depth_scale`` (depth file units per metre)."""
    path = Path(path)
    data = read_json_file(path, "poses file")
    if is_transforms_json(data):  # nerfstudio: OpenGL c2w of EQUIRECTANGULAR frames
        records = read_transforms_json(path, data=data)
        entries = [(r.image, r.c2w.float(), r.depth) for r in records]
        _check_positions(entries, path)
        return entries, True, _depth_scale(data, path)
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
    _check_positions(entries, path)
    return entries, False, _depth_scale(data, path)


def _check_positions(entries, path: Path) -> None:
    """Camera positions within 10 km of the origin (:mod:`cylindersplat.validation`), named by frame."""
    for i, (_, c2w, _) in enumerate(entries):
        check_translation_plausible(c2w, f"{path} frame {i}")


def _depth_scale(data, path: Path) -> float:
    scale = data.get("depth_scale", DEPTH_PNG_SCALE) if isinstance(data, dict) else DEPTH_PNG_SCALE
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not math.isfinite(scale) or scale <= 0:
        raise ValueError(f"{path}: depth_scale must be a positive number, got {scale!r}")
    return float(scale)


# --- the folder -------------------------------------------------------------------------------------------


def _folder_images(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and not p.stem.endswith("_depth"))


def _find_depth(image: Path) -> Path | None:
    for suffix in (".png", ".npy"):
        candidate = image.with_name(f"{image.stem}_depth{suffix}")
        if candidate.is_file():
            return candidate
    return None


def _rebase(name: str, base: Path, folder: Path) -> str:
    return os.path.relpath((base / name).resolve(), folder.resolve())


def _folder_entries(folder: Path, poses_file: Path, allow_outside: bool = False
                    ) -> tuple[list[tuple[str, Tensor, str | None]], bool, float]:
    """``([(image name, c2w, depth file or None)], nerfstudio, depth_scale)`` of an input folder (poses matched
    to the images in name order where the file names none). Named files must lie inside the folder they are
    relative to (:func:`_confine`)."""
    entries, nerfstudio, scale = _read_poses(poses_file)
    _confine(entries, poses_file.parent if nerfstudio else folder, poses_file, allow_outside)
    if nerfstudio and poses_file.parent.resolve() != folder.resolve():  # its names are relative to its own folder
        entries = [(_rebase(name, poses_file.parent, folder), pose, depth and _rebase(depth, poses_file.parent, folder))
                   for name, pose, depth in entries]
    if all(name is None for name, _, _ in entries):
        images = _folder_images(folder)
        if len(images) != len(entries):
            listed = ", ".join(p.name for p in images) or "none"
            raise ValueError(
                f"{poses_file} has {len(entries)} poses but {folder} has {len(images)} panoramas ({listed}); "
                'give one pose per image (matched in name order) or list "frames" with "image" names'
            )
        entries = [(p.name, pose, None) for p, (_, pose, _) in zip(images, entries)]
    elif any(name is None for name, _, _ in entries):
        raise ValueError(f'{poses_file}: every frame needs an "image" name')
    return entries, nerfstudio, scale


def _confine(entries, base: Path, poses_file: Path, allow_outside: bool) -> None:
    """Refuse image/depth names that lead out of ``base`` (the input folder; a nerfstudio file's own folder,
    which its names are relative to), unless ``allow_outside`` (:mod:`.confine`)."""
    for i, (name, _, depth) in enumerate(entries):
        for key, value in (("image", name), ("depth", depth)):
            if value is not None:
                confined_path(base, value, f'{poses_file} frame {i} "{key}"', allow_outside)


def is_input_folder(folder: str | Path) -> bool:
    """Whether ``folder`` holds a poses file (``poses.json`` or a nerfstudio ``transforms.json``)."""
    folder = Path(folder)
    return (folder / POSES_FILE).is_file() or (folder / TRANSFORMS_FILE).is_file()


def poses_path(folder: str | Path, poses_file: str | Path | None = None) -> Path:
    """The poses file: ``poses_file`` if given, else ``poses.json``, else a nerfstudio ``transforms.json``."""
    folder = Path(folder)
    if poses_file is not None:
        return Path(poses_file)
    if not (folder / POSES_FILE).is_file() and (folder / TRANSFORMS_FILE).is_file():
        return folder / TRANSFORMS_FILE
    if not (folder / POSES_FILE).is_file():
        raise FileNotFoundError(f"missing poses file: {folder / POSES_FILE} (or a nerfstudio {TRANSFORMS_FILE}; "
                                "see docs/inference.md)")
    return folder / POSES_FILE


def _check_folder(folder: Path) -> None:
    if not folder.is_dir():
        raise FileNotFoundError(f"input folder not found: {folder}")


def list_panoramas(folder: str | Path, poses_file: str | Path | None = None) -> list[Path]:
    """The panoramas of an input folder, in the order of its poses file."""
    folder = Path(folder)
    _check_folder(folder)
    return [folder / name for name, _, _ in _folder_entries(folder, poses_path(folder, poses_file))[0]]


def input_files(folder: str | Path, poses_file: str | Path | None = None, allow_outside: bool = False) -> list[Path]:
    """What reading an input folder reads: its poses file, and each frame's panorama and depth file (a command that
    writes into a folder must not replace or remove them)."""
    folder = Path(folder)
    _check_folder(folder)
    poses = poses_path(folder, poses_file)
    frames, _ = _folder_frames(folder, poses, allow_outside)
    return [poses, *(f.rgb for f in frames), *(f.depth for f in frames if f.depth is not None)]


def _folder_frames(folder: Path, poses_file: Path, allow_outside: bool = False) -> tuple[list[FrameRef], float]:
    """The frames of one input folder (depth file: ``"depth"`` of the poses file, else ``<stem>_depth.png|.npy``)
    and its ``depth_scale``. Every file must lie inside ``folder`` unless ``allow_outside`` (:mod:`.confine`)."""
    entries, nerfstudio, scale = _folder_entries(folder, poses_file, allow_outside)
    frames = []
    for name, pose, depth_name in entries:
        image = folder / name
        depth = folder / depth_name if depth_name else _find_depth(image)
        if depth is not None and not depth_name:  # found beside the image: may still be a symlink leading out
            confined_path(folder, depth.relative_to(folder), f"{poses_file}: depth of {name}", allow_outside)
        # PNG depth is in depth_scale units; .npy in metres, except nerfstudio's (in the units of its PNGs)
        npy = depth is not None and depth.suffix.lower() == ".npy"
        frames.append(FrameRef(name, image, pose, depth, None if npy and not nerfstudio else scale))
    return frames, scale


class FolderDataset(PanoramaDataset):
    """Folders of posed panoramas in the input format (module docstring; ``docs/inference.md``).

    ``root`` is one input folder (with ``poses.json`` or a nerfstudio ``transforms.json``; ``poses_file``
    names another poses file): one example; or a folder of input folders (every subfolder with a poses
    file, in name order): one example each. Frames keep the order of their poses file.

    ``views`` says which frames are inputs (contexts) and which are targets, per example:

    * ``"all_inputs"`` (default): every frame is an input, no target (what ``render`` / ``export`` reconstruct);
      a frame that repeats an earlier one (same image, pose and depth: :mod:`.repeated_frames`) is used once, with
      a :class:`~cylindersplat.utils.notices.Notice` saying how many were dropped;
    * ``"held_out"``: the frames named in ``targets`` (image names as the poses file lists them, their stems,
      or indices) are the targets, all others the inputs; ``targets``, when given, means this whatever ``views`` says;
    * ``"two_view"``, ``"one_view"``, ``"n_view"``: the protocols of :func:`~cylindersplat.data.views.select_views`
      over the frames in poses-file order (e.g. ``two_view``: first and last in, the middle one out);
    * or a :class:`~cylindersplat.data.views.ViewSplit`.

    Depth files: a frame's depth file is its stored depth. With ``depth_files="prior"`` (default) it is also
    the frame's input prior (``Sample.context_priors``, as ``render`` uses it); ``depth_prior`` gives the prior
    of frames without one (default: none, an error listing them). With ``depth_files="reference"`` the files
    are only the reference of the depth metrics (``Sample.target_depths``, ``context_gt_depths``) and every
    input prior comes from ``depth_prior`` (to score a network prior against measured or rendered depth).
    File priors (``file:NAME``) are read from ``<root>/priors/NAME/<image path relative to root>.png``.

    Image and depth files named by a poses file must resolve inside its input folder (symlinks pointing inside
    are fine); an absolute path or one leading out is an :class:`~cylindersplat.errors.OutsideFolderError`
    unless ``allow_outside_paths=True`` (the CLI's ``--allow-outside-paths``). ``check_plausibility``: the
    bounds every loaded frame is checked against (:meth:`~cylindersplat.data.base.PanoramaDataset.check_frame`).
    """

    dataset_name = "folder"

    def __init__(
        self,
        root: str | Path,
        *,
        views: str | ViewSplit = "all_inputs",
        targets: Sequence[str | int] | None = None,
        resolution: tuple[int, int] | None = None,
        depth_prior: DepthPrior | None = None,
        depth_files: str = "prior",
        poses_file: str | Path | None = None,
        depth_resize: str = "area",
        allow_outside_paths: bool = False,
        check_plausibility: bool = True,
    ) -> None:
        if depth_files not in ("prior", "reference"):
            raise ValueError(f"depth_files must be 'prior' or 'reference', got {depth_files!r}")
        if targets is not None and not isinstance(targets, (list, tuple)):
            raise ValueError(f"targets must be a list of frame names or indices, got {targets!r}")
        if targets is not None:  # the frames to hold out decide the split, whatever the protocol
            views = "held_out"
        if isinstance(views, str) and views not in FOLDER_VIEWS:
            raise ValueError(f"unknown views {views!r} for a folder of panoramas; use one of {', '.join(FOLDER_VIEWS)}")
        if views == "held_out" and not targets:
            raise ValueError("views held_out needs the frames to hold out (targets=[image names], eval --targets)")
        if depth_files == "prior" and not isinstance(depth_prior, StoredDepthPrior):
            depth_prior = StoredDepthPrior(depth_prior)
        super().__init__(resolution, depth_prior, depth_resize=depth_resize)
        self.check_plausibility = check_plausibility
        root = Path(root)
        _check_folder(root)
        self.root = self.data_root = root
        self.views, self.targets, self.depth_files = views, list(targets) if targets else None, depth_files
        if poses_file is not None or is_input_folder(root):
            folders = [(root.name, root, poses_path(root, poses_file))]
        else:
            folders = [(d.name, d, poses_path(d)) for d in sorted(root.iterdir())
                       if d.is_dir() and d.name != PRIORS_DIR and is_input_folder(d)]
            if not folders:
                poses_path(root)  # the missing-poses-file error
        self.scenes: list[tuple[str, Path, list[FrameRef], ViewSplit, float]] = []
        for scene, folder, poses in folders:
            frames, scale = _folder_frames(folder, poses, allow_outside_paths)
            self.scenes.append((scene, folder, frames, self._split(frames, poses), scale))

    def _split(self, frames: list[FrameRef], where: Path) -> ViewSplit:
        n = len(frames)
        if self.views == "all_inputs":  # a frame listed again (same image, pose and depth) is read once
            repeats = set(repeated_frames(frames))
            if repeats:
                said = f"{len(repeats)} frames of {where} repeat" if len(repeats) > 1 else f"1 frame of {where} repeats"
                warnings.warn(f"{said} another (same image, pose and depth): used once", Notice, stacklevel=2)
            return ViewSplit(tuple(i for i in range(n) if i not in repeats), ())
        if self.views != "held_out":
            try:
                return select_views(n, self.views)
            except ValueError as exc:  # e.g. two_view on two panoramas: say which folder, and the way out
                raise ValueError(f"{where}: {exc}; {n} frames here: hold out frames by name instead (targets, "
                                 "eval/data info --targets)") from None
        names = [f.name for f in frames]
        short = [Path(f.rgb).name for f in frames]
        stems = [Path(f.rgb).stem for f in frames]
        held = []
        for target in self.targets:
            if isinstance(target, int) and not isinstance(target, bool) and -n <= target < n:
                index = target % n
            elif isinstance(target, str) and target in names + short + stems:
                index = next(k for k in range(n) if target in (names[k], short[k], stems[k]))
            else:
                raise ValueError(f"{where}: no frame {target!r} to hold out as a target; its "
                                 f"frames: {', '.join(short)}")
            held.append(index)
        context = tuple(k for k in range(n) if k not in held)
        if not context:
            raise ValueError(f"{where}: every frame is held out as a target; keep at least one as an input")
        return ViewSplit(context, tuple(sorted(set(held))))

    def stored_depth_size(self, frame: FrameRef) -> tuple[int, int] | None:
        """A depth file must have its panorama's stored size (a half- or double-size map is a mix-up, not a
        depth of this image)."""
        from PIL import Image

        with Image.open(frame.rgb) as image:  # reads the header only
            return image.height, image.width

    def __len__(self) -> int:
        return len(self.scenes)

    def example(self, index: int) -> ExampleRef:
        scene, folder, frames, views, _ = self.scenes[index]
        return ExampleRef(scene, frames, views, {"folder": str(folder), "views": self.views
                                                 if isinstance(self.views, str) else "custom"})

    def check_depth(self, option: str = "depth_prior") -> None:
        """Without a chosen prior every input frame needs a depth file: ``FileNotFoundError`` listing those
        without one (``option`` names the setting that chooses a prior)."""
        prior = self.depth_prior
        if not (isinstance(prior, StoredDepthPrior) and isinstance(prior.fallback, MissingPrior)):
            return  # a prior for frames without a file (or, depth_files="reference", none: require_depth_prior)
        for _, folder, frames, views, scale in self.scenes:
            missing = [frames[i].name for i in views.context if frames[i].depth is None]
            if missing:
                raise FileNotFoundError(
                    f"no depth prior for {', '.join(missing)} in {folder}: add <image stem>_depth.png (16-bit, "
                    f"{scale:g} per metre) or .npy (metres), or choose {option} (e.g. constant:2.0 or "
                    "exported:depth_net.pt2)")
