"""Notices: things a user should know that are not errors (an optional package missing, a setting unused).

They are ``warnings`` of the :class:`Notice` category, so library users filter or catch them as usual; the
command line prints every warning as one line ``cylindersplat CMD: note: MESSAGE`` (no file, line number or
source text) through :func:`one_line_warnings`.
"""

from __future__ import annotations

import contextlib
import sys
import warnings
from typing import Iterator

__all__ = ["Notice", "notice_once", "one_line_warnings"]


class Notice(UserWarning):
    """Information for the user; nothing failed."""


_said: set[str] = set()


def notice_once(key: str, message: str, stacklevel: int = 3) -> None:
    """Warn ``message`` (a :class:`Notice`) the first time this process reaches ``key``, never again (``stacklevel``
    as ``warnings.warn``'s, counted from this function: 3 is its caller's caller)."""
    if key in _said:
        return
    _said.add(key)
    warnings.warn(message, Notice, stacklevel=stacklevel)


@contextlib.contextmanager
def one_line_warnings(prefix: str) -> Iterator[None]:
    """Within the block, every warning shown is one stderr line ``PREFIX: note: MESSAGE`` (the message's own
    line breaks joined), each distinct message once."""
    shown: set[str] = set()

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        text = " ".join(part.strip() for part in str(message).splitlines() if part.strip())
        if text in shown:
            return
        shown.add(text)
        print(f"{prefix}: note: {text}", file=file or sys.stderr, flush=True)

    original = warnings.showwarning
    warnings.showwarning = show
    try:
        yield
    finally:
        warnings.showwarning = original
