"""Atomic file outputs: write to a temporary name in the same folder, rename on success.

A failure part-way (disk full, file-size limit, a crash) then leaves the previous file at the path
untouched instead of a truncated one, and no half-written file appears under the final name. An
``OSError`` raised while writing names the final path (not the temporary one), so the command line
can say which output did not fit (``cylindersplat.cli.expected_failure``).

A command that writes several files (a render's views, PLY and fly-through) wraps its writing in
:func:`output_set`: every :func:`atomic_path` inside then keeps its finished temporary file, and the whole
set is renamed into place only when the block succeeds. A failure part-way leaves every earlier output as it
was (none of the new files appears) and the exception carries a note naming the files that were not written
(``output_note``, appended to the command's one-line error). Files of an earlier run that the new set does not
replace are removed only after the new set is in place (``stale``).
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import re
import tempfile
from pathlib import Path
from typing import Callable, Iterable, Iterator

__all__ = ["atomic_path", "atomic_write_text", "atomic_write_bytes", "output_set", "OutputSet", "new_folders",
           "written_at_once", "remove_temporaries"]


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
        staging = _current_set.get()
        if staging is None:
            os.replace(tmp, path)
        else:
            staging.stage(tmp, path)  # renamed with the rest of its set
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


_current_set: contextvars.ContextVar["OutputSet | None"] = contextvars.ContextVar("output_set", default=None)
_TEMPORARY = re.compile(r"^\..+\.[A-Za-z0-9_]{8}\.tmp(\.[^/]*)?$")  # what atomic_path's mkstemp names look like


class OutputSet:
    """Finished temporary files waiting to replace their final paths together (see :func:`output_set`)."""

    def __init__(self, folder: Path, planned: Iterable[str | Path] = ()) -> None:
        self.folder = folder
        self.planned = [Path(p) for p in planned]
        self.staged: dict[Path, Path] = {}  # final path -> its finished temporary file
        self.removed: list[Path] = []  # files of an earlier run deleted after the commit

    def stage(self, tmp: Path, final: Path) -> None:
        earlier = self.staged.pop(final, None)
        if earlier is not None and earlier != tmp:
            earlier.unlink(missing_ok=True)  # written twice in one run: the later one counts
        self.staged[final] = tmp

    def commit(self) -> list[Path]:
        for final, tmp in self.staged.items():
            os.replace(tmp, final)
        return list(self.staged)

    def discard(self) -> None:
        for tmp in self.staged.values():
            tmp.unlink(missing_ok=True)

    def note(self, failed: Path | None) -> str:
        """``nothing in OUT was changed (not written: a, b, ...)``."""
        names = [*self.staged, *([failed] if failed is not None else []), *self.planned]
        shown: list[str] = []
        for path in names:
            name = self._name(path)
            if name not in shown:
                shown.append(name)
        listed = ", ".join(shown[:6]) + (f" and {len(shown) - 6} more" if len(shown) > 6 else "")
        return f"nothing in {self.folder} was changed" + (f" (not written: {listed})" if shown else "")

    def _name(self, path: Path) -> str:
        try:
            return str(Path(os.path.abspath(path)).relative_to(os.path.abspath(self.folder)))
        except ValueError:
            return str(path)


def _failed_path(exc: BaseException) -> Path | None:
    filename = getattr(exc, "filename", None)
    return Path(os.fsdecode(filename)) if isinstance(filename, (str, bytes, os.PathLike)) else None


@contextlib.contextmanager
def output_set(folder: str | Path, planned: Iterable[str | Path] = (),
               stale: Callable[[], Iterable[Path]] | None = None) -> Iterator[OutputSet]:
    """``with output_set(OUT): write(...)``: all files written with :func:`atomic_path` in the block replace
    their final paths only when the whole block succeeds.

    A failure discards the new files, leaves ``folder`` as it was and adds ``output_note`` to the exception
    (``nothing in OUT was changed (not written: ...)``, naming the files written so far, the one that failed and
    ``planned``: those the command had still to write). After a success, ``stale()`` (called before the new files
    are renamed into place) lists files of an earlier run; those the new set did not replace are deleted. A set
    opened inside another joins it.
    """
    if _current_set.get() is not None:
        yield _current_set.get()
        return
    staging = OutputSet(Path(folder), planned)
    token = _current_set.set(staging)
    try:
        yield staging
    except BaseException as exc:
        staging.discard()
        if isinstance(exc, Exception) and not hasattr(exc, "output_note"):
            with contextlib.suppress(AttributeError, TypeError):  # some exception types take no attributes
                exc.output_note = staging.note(_failed_path(exc))
        raise
    finally:
        _current_set.reset(token)
    earlier = [Path(p) for p in stale()] if stale is not None else []
    written = {Path(os.path.abspath(p)) for p in staging.commit()}
    staging.removed = [p for p in earlier if Path(os.path.abspath(p)) not in written and p.is_file()]
    for path in staging.removed:
        path.unlink(missing_ok=True)


@contextlib.contextmanager
def new_folders(*folders: str | Path) -> Iterator[None]:
    """``with new_folders(OUT, OUT / "views"), output_set(OUT): ...``: the folders are made (with their parents), and
    if the block fails those this call made are removed again where they are still empty (after an
    :func:`output_set` inside has discarded its files), so that a failed command into a new folder leaves no trace."""
    made: list[Path] = []
    for folder in map(Path, folders):
        made += [d for d in reversed([folder, *folder.parents]) if not d.exists() and d not in made]
        folder.mkdir(parents=True, exist_ok=True)
    try:
        yield
    except BaseException:
        for folder in reversed(made):  # the deepest first
            with contextlib.suppress(OSError):  # not empty (or gone): kept
                folder.rmdir()
        raise


@contextlib.contextmanager
def written_at_once() -> Iterator[None]:
    """Files written in this block go to their final paths at once, also inside an :func:`output_set` (an
    intermediate a command reads back, e.g. the demo's input folder)."""
    token = _current_set.set(None)
    try:
        yield
    finally:
        _current_set.reset(token)


def remove_temporaries(folder: str | Path) -> int:
    """Delete the temporary files :func:`atomic_path` leaves behind when its process is killed (``kill -9``)
    anywhere under ``folder``; returns how many. Only for folders no other process is writing into."""
    count = 0
    for path in Path(folder).rglob(".*.tmp*"):
        if path.is_file() and _TEMPORARY.match(path.name):
            path.unlink(missing_ok=True)
            count += 1
    return count
