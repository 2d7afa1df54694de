"""Progress of a long loop: a tqdm bar on a terminal, plain lines where the output is a file or a pipe.

A tqdm bar written to a log file is one endless line of carriage returns (or nothing: ``tqdm`` disables itself
there), so a job run with ``> log 2>&1`` would show no sign of life until it ends. Lines instead: one at each
of ``lines`` evenly spaced marks, with the elapsed time and an optional note (e.g. the current loss).
"""

from __future__ import annotations

import sys
import time

from tqdm.auto import tqdm

__all__ = ["Progress"]


class Progress:
    """Progress over ``total`` items, starting at ``initial`` (a resumed loop); nothing when not ``enabled``.

    Args:
        total: items of the whole loop.
        desc: what is counted, e.g. ``"stage 1"`` or ``"novel views"``.
        unit: one item's name (``"step"``, ``"view"``); lines say ``unit + "s"``.
        enabled: False makes every call a no-op.
        initial: items already done before this loop (resume).
        lines: how many lines a loop without a terminal prints (at ``total * k / lines``, k = 1..lines).
        stream: where it writes (default ``sys.stderr``); it is a terminal or not.
        announce: without a terminal, also say at once that the loop started (its first mark may be minutes away).
    """

    def __init__(self, total: int, desc: str, unit: str, enabled: bool = True, initial: int = 0, lines: int = 4,
                 stream=None, announce: bool = False) -> None:
        self.total, self.desc, self.unit, self.done = total, desc, unit, initial
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled and total > 0
        on_terminal = hasattr(self.stream, "isatty") and self.stream.isatty()
        self._bar = (tqdm(total=total, initial=initial, desc=desc, unit=unit, file=self.stream, dynamic_ncols=True)
                     if self.enabled and on_terminal else None)
        self._marks = sorted({max(1, round(total * k / lines)) for k in range(1, lines + 1)})
        self._start = time.perf_counter()
        if announce and self.enabled and self._bar is None:
            start = f"started: {total} {unit}s" if initial == 0 else f"resumed at {initial}/{total} {unit}s"
            every = max(1, round(total / lines))
            print(f"{desc} {start}, a line every {f'{every} {unit}s' if every > 1 else unit}", file=self.stream,
                  flush=True)

    def update(self, n: int = 1, note: str = "") -> None:
        """``n`` more items done; ``note`` (e.g. ``"loss 0.0123"``) goes into the bar's postfix or the line."""
        before, self.done = self.done, self.done + n
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.update(n)
            if note:
                self._bar.set_postfix_str(note)
        elif any(before < mark <= self.done for mark in self._marks):
            extra = f", {note}" if note else ""
            print(f"{self.desc}: {self.done}/{self.total} {self.unit}s "
                  f"({time.perf_counter() - self._start:.1f} s{extra})",
                  file=self.stream, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
