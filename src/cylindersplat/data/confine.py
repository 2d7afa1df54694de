"""Files named inside an input file stay inside the input's folder.

A ``poses.json`` (or nerfstudio ``transforms.json``) names its panoramas and depth maps. Those names are
data, possibly from someone else: ``"../outside/x.png"`` or ``"/etc/..."`` would make ``render``/``export``/
``view`` read a file outside the folder and bake it into their outputs. :func:`confined_path` resolves a
name (following symlinks) and refuses it unless it lands inside the folder; symlinks that point inside are
fine. ``allow_outside=True`` (``--allow-outside-paths``) is the explicit way to read such files anyway.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError, OutsideFolderError

__all__ = ["confined_path", "ALLOW_OUTSIDE_OPTION"]

ALLOW_OUTSIDE_OPTION = "--allow-outside-paths"


def confined_path(folder: str | Path, name: str | Path, where: str, allow_outside: bool = False) -> Path:
    """``folder / name``, refused (:class:`OutsideFolderError` naming ``where`` and the name) when it is an
    absolute path or resolves outside ``folder``, unless ``allow_outside``."""
    folder, path = Path(folder), Path(folder) / name
    if allow_outside:
        return path
    if Path(name).is_absolute():
        raise OutsideFolderError(f"{where}: {name} is an absolute path; name files relative to {folder} "
                                 f"(or pass {ALLOW_OUTSIDE_OPTION} to read it anyway)")
    try:
        resolved = path.resolve()
    except (RuntimeError, OSError) as exc:  # Python < 3.13 raises RuntimeError for a loop, later ones OSError
        raise InputError(f"{where}: {name} is a symlink loop (a link that leads back to itself); replace it with the "
                         "file or a link to it") from exc
    if not resolved.is_relative_to(folder.resolve()):
        raise OutsideFolderError(f"{where}: {name} is outside the input folder {folder}; move the file into it "
                                 f"(or pass {ALLOW_OUTSIDE_OPTION} to read it anyway)")
    return path
