"""One ``train`` per run folder: an advisory lock (``fcntl.flock``) on ``RUN/.train.lock``, held while it runs.

The lock is taken before anything else is written into the folder, so two runs started into the same ``--out``
at the same instant cannot both pass the checks and interleave their files: ``flock`` is atomic, and the kernel
releases it when the holder ends in any way (``kill -9`` included), so no stale lock is ever left to clear.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import Iterator

__all__ = ["LOCK_FILE", "RunFolderInUse", "lock_run_folder", "run_folder_lock"]

LOCK_FILE = ".train.lock"


class RunFolderInUse(ValueError):
    """Another process holds the run folder's lock."""


def lock_run_folder(folder: str | Path) -> int | None:
    """Lock ``folder`` (created if missing) for this process; returns the lock's file descriptor (keep it open for
    the run: closing it, or the process ending, releases the lock). None where ``fcntl`` is missing (Windows).
    Raises :class:`RunFolderInUse` naming the holder's process id when another run holds it."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        return None
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    fd = os.open(folder / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.pread(fd, 32, 0).decode(errors="replace").strip()
        os.close(fd)
        by = f" (process {holder})" if holder.isdigit() else ""
        raise RunFolderInUse(f"{folder} is in use by another `cylindersplat train`{by}; wait for it to end, or "
                             "choose another --out") from None
    except BaseException:
        os.close(fd)
        raise
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    return fd


@contextlib.contextmanager
def run_folder_lock(folder: str | Path) -> Iterator[None]:
    """``with run_folder_lock(RUN): train(...)``: :func:`lock_run_folder`, released when the block ends."""
    fd = lock_run_folder(folder)
    try:
        yield
    finally:
        if fd is not None:
            os.close(fd)
