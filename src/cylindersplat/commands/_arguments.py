"""Argument helpers of the subcommands: the shared argparse types (:mod:`cylindersplat.utils.arguments`, re-exported
here), and the ones that need the library (fills, output checks, the renderer's memory advice)."""

from __future__ import annotations

import argparse
import contextlib
from typing import Any, Callable, Iterator

from ..utils.arguments import (  # noqa: F401  (the commands import them from here)
    NearFar,
    count_list,
    device,
    equirect_resolution,
    field_of_view,
    finite_float,
    fraction,
    frame_count,
    image_resolution,
    int_at_least,
    model_resolution,
    nonnegative_int,
    opacity_threshold,
    port_number,
    positive_float,
    positive_int,
    stage_list,
)


def refuse_folder_as_splat_file(path, option: str = "") -> None:
    """A folder given where a splat file is read (``render --ply``, ``view``): ``ValueError`` naming it, with
    ``--input`` as the way to give a folder of posed panoramas."""
    from pathlib import Path

    from ..gaussians.formats import READ_FORMATS

    if Path(path).is_dir():
        named = f"{option} {path}" if option else str(path)
        raise ValueError(f"{named} is a folder: give a splat file ({', '.join(READ_FORMATS)}), or --input {path} for "
                         "a folder of posed panoramas")


def check_output(path, folder: bool, option: str = "--out") -> None:
    """Refuse, before any work, an output the command could not write: a file where a folder is wanted
    (or the reverse), a path under a file, or a folder without write permission. ``ValueError`` naming
    ``option``; what is not there yet is fine (it is created)."""
    import os
    from pathlib import Path

    path = Path(path)
    if path.exists():
        if folder and not path.is_dir():
            raise ValueError(f"{option} {path} is a file, but this command writes a folder "
                             f"there: choose another {option}")
        if not folder and path.is_dir():
            raise ValueError(f"{option} {path} is a folder, but this command writes a file: give a file name in it")
    parent = path if path.is_dir() else path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise ValueError(f"{option} {path}: {parent} is a file, not a folder: choose another {option}")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"{option} {path}: no permission to write in {parent}: choose another {option}")


def fill_list(text: str) -> list[str]:
    """``"mean,inpaint"`` / ``"none"`` -> the fills of the fill rows; an argparse type."""
    from ..evaluation.fills import FILLS

    chosen = [part.strip() for part in text.split(",") if part.strip()]
    if chosen == ["none"]:
        return []
    bad = [part for part in chosen if part not in FILLS]
    if bad or not chosen:
        raise argparse.ArgumentTypeError(f"expected none or a comma list of {', '.join(FILLS)}, got {text!r}")
    return chosen


@contextlib.contextmanager
def memory_advice(advice: str | Callable[[Any], str]) -> Iterator[None]:
    """Within the block (or the decorated command), the renderer's memory refusal ends in ``advice`` (the
    command's own options; or ``advice(refusal)``) instead of the library's generic words."""
    from ..render.rasterize import RenderMemoryError

    try:
        yield
    except RenderMemoryError as exc:
        raise exc.advise(advice(exc) if callable(advice) else advice) from None
