"""Argument types shared by the subcommands."""

from __future__ import annotations

import argparse
import contextlib
import math
from typing import Any, Callable, Iterator


def equirect_resolution(text: str, min_height: int = 1) -> tuple[int, int]:
    """``"HxW"`` -> ``(H, W)`` for an equirect panorama (W == 2H, H >= ``min_height``); an argparse type."""
    h, _, w = text.lower().partition("x")
    try:
        size = int(h), int(w)
    except ValueError:
        raise argparse.ArgumentTypeError(f"resolution must be HxW, e.g. 256x512, got {text!r}") from None
    if size[1] != 2 * size[0] or size[0] < min_height:
        raise argparse.ArgumentTypeError(f"equirect resolution needs W == 2H (H >= {min_height}), got {text!r}")
    return size


def image_resolution(text: str) -> tuple[int, int]:
    """``"HxW"`` -> ``(H, W)``, any positive size (pinhole views; panoramas are checked for W == 2H later)."""
    h, _, w = text.lower().partition("x")
    try:
        size = int(h), int(w)
    except ValueError:
        raise argparse.ArgumentTypeError(f"resolution must be HxW, e.g. 256x512, got {text!r}") from None
    if min(size) < 1:
        raise argparse.ArgumentTypeError(f"resolution must be positive, got {text!r}")
    return size


def int_at_least(minimum: int, meaning: str = ""):
    """An argparse type for integers >= ``minimum`` (``meaning``: a word on what the bound means)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = minimum - 1
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}{meaning}, got {text!r}")
        return value

    return parse


positive_int = int_at_least(1)
nonnegative_int = int_at_least(0)  # a count where 0 means none


def positive_float(text: str) -> float:
    """A finite number > 0 (metres, scales)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def fraction(text: str) -> float:
    """A share in [0, 1]; an argparse type."""
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0 <= value <= 1:  # also false for nan
        raise argparse.ArgumentTypeError(f"expected a share in [0, 1], got {text!r}")
    return value


class NearFar(argparse.Action):
    """``--OPTION NEAR FAR``: two finite numbers with 0 <= NEAR < FAR (metres), checked together."""

    def __call__(self, parser, namespace, values, option_string=None):
        try:
            near, far = (float(v) for v in values)
        except ValueError:
            near = far = float("nan")
        if not (math.isfinite(near) and math.isfinite(far) and 0 <= near < far):
            parser.error(f"argument {option_string}: expected NEAR FAR in metres with 0 <= NEAR < FAR (e.g. 0.05 1000), "
                         f"got {' '.join(values)}")
        setattr(namespace, self.dest, (near, far))


def count_list(text: str) -> str:
    """``"100"`` or ``"100,200,50"``: integers >= 0 (``--steps``); an argparse type, kept as the text."""
    parts = [part.strip() for part in text.split(",")]
    if not all(part.isdigit() for part in parts):
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0 or a comma list of them (e.g. 100 or "
                                         f"100,200,50), got {text!r}")
    return ",".join(parts)


def stage_list(text: str) -> str:
    """``"1,2,3"``, ``"3"``: curriculum stages (``--stages``); an argparse type, kept as the text."""
    parts = [part.strip() for part in text.split(",")]
    if not all(part in ("1", "2", "3") for part in parts):
        raise argparse.ArgumentTypeError(f"expected a comma list of the stages 1, 2, 3 (e.g. 1,2,3 or 3), got {text!r}")
    return ",".join(parts)


def opacity_threshold(text: str) -> float:
    """A minimum opacity in [0, 1) (``--min-opacity``: 1 or more would drop every Gaussian); an argparse type."""
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0 <= value < 1:  # also false for nan
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1) (Gaussians at or below it are dropped), got {text!r}")
    return value


def model_resolution(text: str) -> tuple[int, int]:
    """An equirect resolution the model can run at (the backbone downsamples: H >= 8)."""
    return equirect_resolution(text, min_height=8)


def device(text: str) -> str:
    """``auto`` (CUDA when available, else CPU), ``cpu``, ``cuda``, ``cuda:N``; an argparse type that
    refuses a CUDA device this machine does not have (one line instead of a traceback later)."""
    import torch

    name = text.strip().lower()
    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    try:
        dev = torch.device(name)
    except RuntimeError:
        raise argparse.ArgumentTypeError(f"not a torch device: {text!r} (auto, cpu, cuda, cuda:1, ...)") from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise argparse.ArgumentTypeError(f"{text!r}: this machine has no usable CUDA GPU; use cpu or auto")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise argparse.ArgumentTypeError(f"{text!r}: only {torch.cuda.device_count()} CUDA device(s) here")
    elif dev.type != "cpu":
        raise argparse.ArgumentTypeError(f"unsupported device {text!r}; use auto, cpu or cuda[:N]")
    return name


def check_output(path, folder: bool, option: str = "--out") -> None:
    """Refuse, before any work, an output the command could not write: a file where a folder is wanted
    (or the reverse), a path under a file, or a folder without write permission. ``ValueError`` naming
    ``option``; what is not there yet is fine (it is created)."""
    import os
    from pathlib import Path

    path = Path(path)
    if path.exists():
        if folder and not path.is_dir():
            raise ValueError(f"{option} {path} is a file, but this command writes a folder there: choose another {option}")
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
