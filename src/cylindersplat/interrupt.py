"""Ctrl-C ends a command with one line, ``cylindersplat CMD: interrupted``, and exit status 130, at any moment.

Two phases (stdlib only here, so that importing this module is the first thing the executable does):

* :func:`exit_at_once`, installed by :mod:`cylindersplat.console` before the command line's modules are imported:
  nothing has been written yet, so Ctrl-C prints the line and ends the process at once. (Earlier still, while
  Python itself starts and runs ``site``, the interpreter's own handling applies.)
* :func:`remember`, installed by :func:`cylindersplat.cli.main`: Ctrl-C raises ``KeyboardInterrupt`` as usual, so
  ``finally`` blocks remove half-written files, and is remembered, because some libraries turn it into an error
  of their own (numpy's C extensions, interrupted while importing, raise an ``ImportError``); :func:`received`
  tells the command line that such an error is an interrupt.

:func:`held` keeps Ctrl-C back for a few lines that must run whole (a training step's optimizer update): the
interrupt is raised when the block ends, so a checkpoint written then holds a consistent state.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from typing import Iterator

__all__ = ["command_name", "exit_at_once", "remember", "received", "restore", "held"]

_received = False


def command_name(argv: list[str] | None = None) -> str:
    """``cylindersplat train``: the program and its first word, known before (or without) parsing."""
    words = [a for a in (sys.argv[1:] if argv is None else argv) if not a.startswith("-")]
    return f"cylindersplat {words[0]}" if words else "cylindersplat"


def _exit(signum, frame) -> None:
    os.write(2, f"{command_name()}: interrupted\n".encode())
    os._exit(130)


def exit_at_once() -> None:
    """From now on Ctrl-C prints the line and ends the process (for start-up, before anything is written)."""
    signal.signal(signal.SIGINT, _exit)


def _remember(signum, frame) -> None:
    global _received
    _received = True
    raise KeyboardInterrupt


def remember():
    """Ctrl-C raises ``KeyboardInterrupt`` and is remembered (:func:`received`); returns the handler it replaces
    (for :func:`restore`), or None where handlers cannot be set (not the main thread)."""
    global _received
    _received = False
    try:
        return signal.signal(signal.SIGINT, _remember)
    except ValueError:  # signal handlers belong to the main thread; elsewhere Python's own applies
        return None


def restore(previous) -> None:
    """Put back the handler :func:`remember` replaced (a library caller's, e.g. pytest's); the interrupt it
    remembered is forgotten (it belonged to that command)."""
    global _received
    _received = False
    if previous is not None:
        signal.signal(signal.SIGINT, previous)


def received() -> bool:
    """Whether Ctrl-C was pressed since :func:`remember`."""
    return _received


@contextlib.contextmanager
def held() -> Iterator[None]:
    """Ctrl-C inside the block is raised (as ``KeyboardInterrupt``) only when the block has run whole. Where
    handlers cannot be set (not the main thread) the block runs as it is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pressed = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: pressed.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if pressed and previous is not signal.SIG_IGN:
        raise KeyboardInterrupt
