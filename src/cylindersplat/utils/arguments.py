"""Argument parsing every entry point shares (the ``cylindersplat`` command, ``cylindersplat bench``, the scripts):
:class:`OneLineErrorParser` and the argparse types (``type=`` / ``action=``) of sizes, counts, shares and devices.
A base layer: it imports nothing of the library, so library modules with a command line of their own (the bench
modules) need not import the CLI.
"""

from __future__ import annotations

import argparse
import math

__all__ = ["OneLineErrorParser", "equirect_resolution", "image_resolution", "int_at_least", "positive_int",
           "nonnegative_int", "positive_float", "fraction", "NearFar", "count_list", "stage_list", "opacity_threshold",
           "model_resolution", "device"]


class OneLineErrorParser(argparse.ArgumentParser):
    """argparse with its errors on one line (what is wrong, then where to read more) instead of the
    whole usage block; subcommand parsers inherit it."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")

    def parse_args(self, args=None, namespace=None):
        """Unknown options are reported by the subcommand's parser (its --help), with the nearest known option."""
        parsed, extras = self.parse_known_args(args, namespace)
        if extras:
            parser = self._subcommand_parser(getattr(parsed, "command", None)) or self
            parser.error(f"unrecognized arguments: {' '.join(extras)}{_did_you_mean(parser, extras)}")
        return parsed

    def _subcommand_parser(self, name: str | None) -> argparse.ArgumentParser | None:
        for action in self._actions:
            if isinstance(action, argparse._SubParsersAction) and name in action.choices:
                return action.choices[name]
        return None


def _did_you_mean(parser: argparse.ArgumentParser, extras: list[str]) -> str:
    """`` (did you mean --frames?)`` for the first unknown option close to one of ``parser``'s, else ``""``."""
    import difflib

    known = [option for action in parser._actions for option in action.option_strings if option.startswith("--")]
    for word in extras:
        if word.startswith("--"):
            close = difflib.get_close_matches(word.split("=", 1)[0], known, n=1)
            if close:
                return f" (did you mean {close[0]}?)"
    return ""


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
            parser.error(f"argument {option_string}: expected NEAR FAR in metres with 0 <= NEAR < FAR "
                         f"(e.g. 0.05 1000), got {' '.join(values)}")
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


def frame_count(text: str) -> int:
    """A fly-through's length: 0 (none) or 2 frames or more; an argparse type."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0 or value == 1:
        raise argparse.ArgumentTypeError(f"expected 0 (no fly-through) or a number of frames >= 2, got {text!r}")
    return value


def port_number(text: str) -> int:
    """A TCP port, 0-65535 (0: one the system picks); an argparse type."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"expected a port number from 1 to 65535 (0: any free port), got {text!r}")
    return value


def field_of_view(text: str) -> float:
    """A pinhole camera's horizontal field of view in degrees, in (0, 180); an argparse type."""
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0 < value < 180:  # also false for nan
        raise argparse.ArgumentTypeError(f"expected a field of view in degrees between 0 and 180 (e.g. 90), got "
                                         f"{text!r}")
    return value


def finite_float(text: str) -> float:
    """Any finite number (an angle, an offset); an argparse type."""
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def opacity_threshold(text: str) -> float:
    """A minimum opacity in [0, 1) (``--min-opacity``: 1 or more would drop every Gaussian); an argparse type."""
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0 <= value < 1:  # also false for nan
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1) (Gaussians at or below it are dropped), "
                                         f"got {text!r}")
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
