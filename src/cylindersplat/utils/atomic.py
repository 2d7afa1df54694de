"""Atomic file outputs: write to a temporary name in the same folder, rename on success.

A failure part-way (disk full, file-size limit, a crash) then leaves the previous file at the path
untouched instead of a truncated one, and no half-written file appears under the final name. An
``OSError`` raised while writing names the final path (not the temporary one), so the command line
can say which output did not fit (``cylindersplat.cli.expected_failure``).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Iterator

__all__ = ["atomic_path", "atomic_write_text", "atomic_write_bytes"]


def _umask() -> int:
    """The process umask, without changing it where /proc says it (os.umask can only be read by setting it)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _final_mode(path: Path) -> int:
    """An existing file keeps its permissions; a new one gets what ``open()`` would give it (mkstemp: 0600)."""
    try:
        return path.stat().st_mode & 0o7777
    except OSError:
        return 0o666 & ~_umask()


def _named(exc: OSError, path: Path) -> OSError:
    """``exc`` naming ``path`` where it named one of our temporary files or nothing."""
    if exc.errno is None:
        return exc
    if exc.filename is not None:
        name = Path(os.fsdecode(exc.filename)).name if isinstance(exc.filename, (str, bytes, os.PathLike)) else ""
        if not (name.startswith(f".{path.stem}.") and ".tmp" in name):
            return exc
    return type(exc)(exc.errno, exc.strerror or os.strerror(exc.errno), str(path))


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """``with atomic_path(p) as tmp: write(tmp)`` -> ``tmp`` replaces ``p`` only if the block succeeds.

    The temporary file keeps ``p``'s suffix (writers that pick a format by suffix still work) and
    lives in ``p``'s folder (so the final rename is atomic on POSIX file systems). The result has the
    permissions of the file it replaces (a new file: those the umask gives).
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
        os.close(fd)
    except OSError as exc:
        named = _named(exc, path)
        if named is exc:
            raise
        raise named from exc
    tmp = Path(name)
    try:
        yield tmp
        os.chmod(tmp, _final_mode(path))
        os.replace(tmp, path)
    except BaseException as exc:
        tmp.unlink(missing_ok=True)
        if isinstance(exc, OSError):
            named = _named(exc, path)
            if named is not exc:
                raise named from exc
        raise


def atomic_write_text(path: str | Path, text: str) -> Path:
    """``Path.write_text``, atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def atomic_write_bytes(path: str | Path, data: bytes | bytearray | memoryview) -> Path:
    """``Path.write_bytes``, atomically. Serialise to memory first (``torch.save`` to a ``BytesIO``,
    ``safetensors.torch.save``) and write with this: a full disk is then an ``OSError`` naming ``path``
    (writers that stream to a path themselves report it as an opaque ``RuntimeError``)."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
    return Path(path)
