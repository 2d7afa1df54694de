"""Training metrics to ``metrics.jsonl`` and image grids to ``images/*.png`` (always), and both to
TensorBoard (only if it is installed)."""

from __future__ import annotations

import json
import time
from pathlib import Path

from ..utils.notices import notice_once

__all__ = ["MetricLogger"]


class MetricLogger:
    """Append-only log; safe to reopen when resuming (lines after the resume step are kept as is)."""

    def __init__(self, folder: str | Path, tensorboard: bool = True, enabled: bool = True) -> None:
        self.enabled = enabled
        self.folder = Path(folder)
        self.writer = None
        if not enabled:
            return
        self.folder.mkdir(parents=True, exist_ok=True)
        self.jsonl = (self.folder / "metrics.jsonl").open("a")
        if tensorboard:
            try:
                from torch.utils.tensorboard import SummaryWriter  # needs the optional `tensorboard` package
            except ImportError:
                SummaryWriter = None
                notice_once("tensorboard", "TensorBoard logs are skipped: the tensorboard package is not installed "
                            "(pip install -e '.[train]', or train.tensorboard=false to silence this); "
                            "metrics.jsonl and images/ are written as always")
            if SummaryWriter is not None:
                self.writer = SummaryWriter(str(self.folder / "tensorboard"))

    @property
    def backends(self) -> list[str]:
        return (["jsonl"] + (["tensorboard"] if self.writer else [])) if self.enabled else []

    def log(self, step: int, values: dict[str, float], **context) -> None:
        if not self.enabled:
            return
        record = {"step": step, "time": round(time.time(), 3), **context, **values}
        self.jsonl.write(json.dumps(record) + "\n")
        self.jsonl.flush()
        if self.writer is not None:
            for key, value in values.items():
                self.writer.add_scalar(key, value, step)

    def log_image(self, step: int, name: str, image) -> None:
        """``image``: float ``(3, H, W)`` in [0, 1] (a grid); written as PNG and to TensorBoard."""
        if not self.enabled:
            return
        from ..data.io import write_rgb

        write_rgb(self.folder / "images" / f"{name}_{step:07d}.png", image)
        if self.writer is not None:
            self.writer.add_image(name, image.detach().float().clamp(0, 1).cpu(), step)

    def close(self) -> None:
        if not self.enabled:
            return
        self.jsonl.close()
        if self.writer is not None:
            self.writer.close()
