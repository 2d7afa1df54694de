"""Argument types shared by the subcommands."""

from __future__ import annotations

import argparse


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


def model_resolution(text: str) -> tuple[int, int]:
    """An equirect resolution the model can run at (the backbone downsamples: H >= 8)."""
    return equirect_resolution(text, min_height=8)
