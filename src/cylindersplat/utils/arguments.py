"""Argument parsing every entry point shares (the ``cylindersplat`` command, ``cylindersplat bench``, the scripts):
:class:`OneLineErrorParser` and the argparse types (``type=`` / ``action=``) of sizes, counts, shares and devices.
A base layer: it imports nothing of the library, so library modules with a command line of their own (the bench
modules) need not import the CLI.
"""

from __future__ import annotations

import argparse
import math

__all__ = ["OneLineErrorParser", "equirect_resolution", "image_resolution", "checked_number", "int_at_least",
           "positive_int", "nonnegative_int", "positive_float", "fraction", "finite_float", "field_of_view",
           "frame_count", "port_number", "NearFar", "count_list", "stage_list", "opacity_threshold",
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


def checked_number(convert, accept, expected: str, name: str):
    """An argparse type: ``convert(text)`` (``int`` or ``float``) where ``accept(value)`` holds, else the one-line
    error ``expected EXPECTED, got 'TEXT'`` (text that does not convert, NaN included, is never accepted)."""

    def parse(text: str):
        try:
            value = convert(text)
        except ValueError:
            value = None
        if value is None or (isinstance(value, float) and math.isnan(value)) or not accept(value):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return value

    parse.__name__ = parse.__qualname__ = name
    return parse


def int_at_least(minimum: int, meaning: str = ""):
    """An argparse type for integers >= ``minimum`` (``meaning``: a word on what the bound means)."""
    return checked_number(int, lambda v: v >= minimum, f"an integer >= {minimum}{meaning}", f"int_at_least_{minimum}")


positive_int = int_at_least(1)
nonnegative_int = int_at_least(0)  # a count where 0 means none
positive_float = checked_number(float, lambda v: math.isfinite(v) and v > 0, "a positive number",
                                "positive_float")  # metres, scales, rates
fraction = checked_number(float, lambda v: 0 <= v <= 1, "a share in [0, 1]", "fraction")
finite_float = checked_number(float, math.isfinite, "a finite number", "finite_float")  # an angle, an offset
field_of_view = checked_number(float, lambda v: 0 < v < 180, "a field of view in degrees between 0 and 180 (e.g. 90)",
                               "field_of_view")  # a pinhole camera's horizontal one
frame_count = checked_number(int, lambda v: v == 0 or v >= 2, "0 (no fly-through) or a number of frames >= 2",
                             "frame_count")
port_number = checked_number(int, lambda v: 0 <= v <= 65535, "a port number from 1 to 65535 (0: any free port)",
                             "port_number")
# --min-opacity: 1 or more would drop every Gaussian
opacity_threshold = checked_number(float, lambda v: 0 <= v < 1,
                                   "a number in [0, 1) (Gaussians at or below it are dropped)", "opacity_threshold")


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
