"""A grid of equally sized pictures on white, optionally with a caption strip over each row and column titles.

Comparison pictures (eval's examples, the demo's ``comparison.png``) put ground truth and methods in rows and
RGB | depth in columns; without words on the picture, which row is which must be looked up elsewhere.
"""

from __future__ import annotations

import numpy as np
from PIL import Image, ImageDraw, ImageFont

__all__ = ["picture_grid", "LABEL_HEIGHT", "GAP"]

GAP = 4  # pixels of white between cells
LABEL_HEIGHT = 14  # pixels of a caption strip (Pillow's default font, 10-11 px tall, with a margin)


def _caption(width: int, texts: list[tuple[int, str]]) -> np.ndarray:
    """A white strip ``(LABEL_HEIGHT, width, 3)`` with each ``(x, text)`` written in black from column ``x``."""
    strip = Image.new("RGB", (width, LABEL_HEIGHT), (255, 255, 255))
    draw = ImageDraw.Draw(strip)
    font = ImageFont.load_default()
    for x, text in texts:
        draw.text((x + 1, 1), text, fill=(0, 0, 0), font=font)
    return np.asarray(strip)


def picture_grid(rows: list[list[np.ndarray]], row_labels: list[str] | None = None,
                 column_labels: list[str] | None = None) -> np.ndarray:
    """uint8 ``(H_total, C * (W + GAP) - GAP, 3)``: ``rows[r][c]`` (each uint8 ``(H, W, 3)``, all one size) at row
    ``r``, column ``c``. ``column_labels`` add a strip of titles on top (one over each column), ``row_labels`` a
    caption strip above each row; each strip is :data:`LABEL_HEIGHT` pixels high."""
    h, w = rows[0][0].shape[:2]
    columns = len(rows[0])
    width = columns * (w + GAP) - GAP
    parts: list[np.ndarray] = []
    if column_labels is not None:
        parts.append(_caption(width, [(c * (w + GAP), text) for c, text in enumerate(column_labels)]))
    for r, cells in enumerate(rows):
        if r > 0 or parts:
            parts.append(np.full((GAP, width, 3), 255, np.uint8))
        if row_labels is not None:
            parts.append(_caption(width, [(0, row_labels[r])]))
        line = np.full((h, width, 3), 255, np.uint8)
        for c, cell in enumerate(cells):
            line[:, c * (w + GAP): c * (w + GAP) + w] = cell
        parts.append(line)
    return np.concatenate(parts, axis=0)
