"""One ``train`` per run folder: an advisory lock (``fcntl.flock``) on ``RUN/.train.lock``, held while it runs.

The lock is taken before anything else is written into the folder, so two runs started into the same ``--out``
at the same instant cannot both pass the checks and interleave their files: ``flock`` is atomic, and the kernel
releases it when the holder ends in any way (``kill -9`` included), so no stale lock is ever left to clear.

The ranks of one ``torchrun`` job are one run: the holder writes its job's key (rendezvous id, master address and
port, which no two live jobs share) next to its process id, and a rank of the same job finds its key there and goes
on without the lock; a separate command (another job, or a plain run) is refused.
"""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path
from typing import Iterator

__all__ = ["LOCK_FILE", "RunFolderInUse", "lock_run_folder", "run_folder_lock"]

LOCK_FILE = ".train.lock"


class RunFolderInUse(ValueError):
    """Another process holds the run folder's lock."""


def lock_run_folder(folder: str | Path) -> int | None:
    """Lock ``folder`` (created if missing) for this process; returns the lock's file descriptor (keep it open for
    the run: closing it, or the process ending, releases the lock). None where ``fcntl`` is missing (Windows), or
    where another rank of this process's own ``torchrun`` job holds the lock (the job shares the run).
    Raises :class:`RunFolderInUse` naming the holder's process id when another run holds it."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        return None
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    fd = os.open(folder / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o644)
    job = _job_key()
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = _read_holder(fd, job)
        os.close(fd)
        if job is not None and holder[1:] == [job]:
            return None  # a rank of this same job holds it
        by = f" (process {holder[0]})" if holder and holder[0].isdigit() else ""
        raise RunFolderInUse(f"{folder} is in use by another `cylindersplat train`{by}; wait for it to end, or "
                             "choose another --out") from None
    except BaseException:
        os.close(fd)
        raise
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}{'' if job is None else ' ' + job}\n".encode(), 0)
    return fd


def _job_key() -> str | None:
    """This process's ``torchrun`` job (the same in all its ranks, on every node), or None outside a multi-process
    job. The rendezvous id alone is not enough: without ``--standalone`` it defaults to ``none`` in every job."""
    if int(os.environ.get("WORLD_SIZE", "1")) <= 1:
        return None
    parts = [os.environ.get(name, "") for name in ("TORCHELASTIC_RUN_ID", "MASTER_ADDR", "MASTER_PORT")]
    return "@".join(part.replace(" ", "_") for part in parts)


def _read_holder(fd: int, job: str | None) -> list[str]:
    """The holder's line split in words (process id, then its job key if any). The holder writes it just after
    taking the lock, over the line of the run before, so a line not yet complete, or (for a rank of a job) one of
    another job, is read again for up to a second."""
    deadline = time.monotonic() + 1.0
    while True:
        line = os.pread(fd, 4096, 0).decode(errors="replace")
        settled = line.endswith("\n") and (job is None or line.split()[1:] == [job])
        if settled or time.monotonic() > deadline:
            return line.split()
        time.sleep(0.01)


@contextlib.contextmanager
def run_folder_lock(folder: str | Path) -> Iterator[None]:
    """``with run_folder_lock(RUN): train(...)``: :func:`lock_run_folder`, released when the block ends."""
    fd = lock_run_folder(folder)
    try:
        yield
    finally:
        if fd is not None:
            os.close(fd)
