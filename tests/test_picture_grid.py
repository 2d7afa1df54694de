"""Comparison pictures say what their rows and columns are."""

from __future__ import annotations

import numpy as np
import torch
from PIL import Image, ImageDraw, ImageFont

from cylindersplat.evaluation.evaluate import comparison_image
from cylindersplat.utils.picture_grid import GAP, LABEL_HEIGHT


def _text_strip(width: int, text: str, x: int = 0) -> np.ndarray:
    """Black text on white, drawn directly with Pillow's default font."""
    strip = Image.new("RGB", (width, LABEL_HEIGHT), "white")
    ImageDraw.Draw(strip).text((x + 1, 1), text, fill="black", font=ImageFont.load_default())
    return np.asarray(strip)


def test_comparison_rows_and_columns_are_labelled():
    rgb, depth = torch.rand(3, 20, 40), torch.rand(20, 40) + 1
    renders = {"CylinderSplat": (rgb * 0, depth, torch.ones(20, 40)), "Forward warp": (rgb, depth, torch.ones(20, 40))}
    plain = comparison_image(rgb, depth, renders, labels=False)
    sheet = comparison_image(rgb, depth, renders)
    width = 2 * 40 + GAP
    assert sheet.shape == (LABEL_HEIGHT + 3 * (GAP + LABEL_HEIGHT + 20), width, 3)
    titles = np.minimum(_text_strip(width, "RGB"), _text_strip(width, "depth (near blue, far red)", 40 + GAP))
    np.testing.assert_array_equal(sheet[:LABEL_HEIGHT], titles)
    for r, name in enumerate(["ground truth", "CylinderSplat", "Forward warp"]):
        top = LABEL_HEIGHT + r * (GAP + LABEL_HEIGHT + 20) + GAP
        np.testing.assert_array_equal(sheet[top:top + LABEL_HEIGHT], _text_strip(width, name))
        cells = sheet[top + LABEL_HEIGHT:top + LABEL_HEIGHT + 20]
        np.testing.assert_array_equal(cells, plain[r * (20 + GAP):r * (20 + GAP) + 20])  # the pictures themselves
