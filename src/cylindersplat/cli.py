"""The ``cylindersplat`` command line.

Each subcommand lives in its own module exposing ``register(subparsers)``, which adds an argparse
sub-parser whose ``func`` attribute runs the command with the parsed namespace. Add a subcommand by
adding a module to ``cylindersplat/commands/``: every module there is registered, in name order.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import os
import pkgutil
import re
import sys
from pathlib import Path

from . import interrupt
from .utils.arguments import OneLineErrorParser


def subcommand_modules() -> list[str]:
    """Every module of ``cylindersplat.commands`` (those starting with ``_`` are helpers)."""
    from . import commands

    names = sorted(m.name for m in pkgutil.iter_modules(commands.__path__) if not m.name.startswith("_"))
    return [f"{commands.__name__}.{name}" for name in names]


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The whole command line, or with ``command`` (a subcommand's name) that command's parser and the others as bare
    names: some commands' parsers import heavy modules to list their choices (torch, about 1.5 s), which the run or
    ``--help`` of another command need not wait for."""
    from . import __version__

    parser = OneLineErrorParser(
        prog="cylindersplat",
        description="Feed-forward 3D Gaussian Splatting from posed 360-degree panoramas.",
    )
    parser.add_argument("--version", action="version", version=f"cylindersplat {__version__}")
    parser.add_argument("--debug", action="store_true", help="show the full traceback of an error")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module in subcommand_modules():
        if command is None or module.rsplit(".", 1)[1] == command:
            importlib.import_module(module).register(sub)
        else:
            sub.add_parser(module.rsplit(".", 1)[1])  # a name to choose from, never parsed with
    return parser


def _command_in(argv: list[str] | None) -> str | None:
    """The subcommand ``argv`` names (its first word that is not an option: the top-level options take no value), ""
    for ``--version`` alone, or None where it names none that exists (the whole parser then says what is wrong)."""
    names = {module.rsplit(".", 1)[1] for module in subcommand_modules()}
    argv = sys.argv[1:] if argv is None else argv
    word = next((a for a in argv if not a.startswith("-")), None)
    if word is None and "--version" in argv and not {"-h", "--help"} & set(argv):
        return ""  # the version alone: no command's parser is needed
    return word if word in names else None


def main(argv: list[str] | None = None) -> int:
    """Run one command; process faults end in one line (or none) instead of a traceback: Ctrl-C at any
    moment, the start-up imports included, prints ``interrupted`` and exits 130 (files are written atomically,
    so none is left half-written; an error a library made of the interrupt counts as one, see
    :mod:`cylindersplat.interrupt`); a reader that stops early (``| head``) ends the output quietly (exit 0: the
    command did its job)."""
    previous = interrupt.remember()
    _closed_streams_to_devnull()
    try:
        code = _run_command(argv)
        sys.stdout.flush()  # a closed pipe shows here, not in the interpreter's own flush at exit
        return code
    except KeyboardInterrupt:
        return _interrupted(argv)
    except BrokenPipeError:
        _silence_stdout()
        return 0  # the reader took what it wanted (`| head`): the command itself did its job
    except Exception:
        if interrupt.received():  # e.g. numpy's ImportError when Ctrl-C hits its C extensions' import
            return _interrupted(argv)
        raise
    finally:
        interrupt.restore(previous)


def _interrupted(argv: list[str] | None) -> int:
    print(f"{interrupt.command_name(argv)}: interrupted", file=sys.stderr)
    return 130


def _closed_streams_to_devnull() -> None:
    """Started with stdout or stderr closed (``>&-``), Python has ``None`` there: print into /dev/null instead."""
    for name in ("stdout", "stderr"):
        if getattr(sys, name) is None:
            setattr(sys, name, open(os.devnull, "w"))  # noqa: SIM115 - lives as long as the process


def _silence_stdout() -> None:
    """Point stdout at /dev/null so the interpreter's last flush does not raise a second BrokenPipeError."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):  # stdout is no real file (captured in tests)
        pass


def _run_command(argv: list[str] | None) -> int:
    from .utils.allocator import keep_freed_memory
    from .utils.notices import one_line_warnings

    parser = build_parser(_command_in(argv))
    args = parser.parse_args(argv)
    keep_freed_memory()  # the CPU renderer reuses large buffers (see utils.allocator)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        with one_line_warnings(f"cylindersplat {args.command}"):  # notices, not tracebacks-like source lines
            result = args.func(args)
    except (KeyboardInterrupt, BrokenPipeError):
        raise  # main's: one line, or a quiet end
    except Exception as exc:  # noqa: BLE001 - sorted into expected failures and bugs below
        if interrupt.received():
            raise  # main's: whatever a library made of Ctrl-C, it was an interrupt
        message = None if args.debug else expected_failure(exc)
        if message is None:
            raise  # a bug (or --debug): the traceback is what we need
        if args.command in OUTPUT_OPTIONS:  # a command whose outputs are not named by --out
            message = message.replace("another --out", f"another place for {OUTPUT_OPTIONS[args.command]}")
        note = getattr(exc, "output_note", None)  # a failed set of outputs: what was kept, what was not written
        if note:
            message = f"{message.rstrip('.')}; {note}"
        # Expected failures: one clear line, no traceback.
        message = " ".join(line.strip() for line in message.splitlines() if line.strip())
        print(f"cylindersplat {args.command}: error: {message}", file=sys.stderr)
        return 1
    return int(result or 0)


# Commands that write their outputs through options other than --out (the file-system messages name --out)
OUTPUT_OPTIONS = {"view": "--html / --screenshot"}


def expected_failure(exc: BaseException) -> str | None:
    """One line for failures a user can fix (bad input, missing files or packages, no CUDA, full disk,
    out of memory); ``None`` for anything else, which is a bug and keeps its traceback."""
    import torch

    os_error = _os_error(exc)
    if os_error is not None:
        message = _file_system_failure(os_error)
        if message is not None:
            return message
    if isinstance(exc, MemoryError):
        # Our own estimates before allocating (RenderMemoryError, ...) carry numbers and advice.
        return str(exc) if str(exc) else OUT_OF_MEMORY
    text = str(exc)
    if isinstance(exc, torch.OutOfMemoryError) or (isinstance(exc, RuntimeError) and any(
            s in text for s in ("can't allocate memory", "CUDA out of memory", "CUDA error: out of memory"))):
        return f"{OUT_OF_MEMORY} ({text.splitlines()[0][:200] if text else type(exc).__name__})"
    if isinstance(exc, RuntimeError) and "PytorchStreamWriter failed writing" in text:
        return ("writing a PyTorch file failed (is the disk full or the folder not writable?): free "
                "space or choose another --out")
    if isinstance(exc, (ValueError, FileNotFoundError)):
        return text
    if isinstance(exc, ModuleNotFoundError):
        if "pip install" in str(exc):  # our own message already says what to install
            return str(exc)
        return f"the optional package {exc.name!r} is not installed ({exc}); install it with pip"
    if isinstance(exc, (AssertionError, RuntimeError)) and _no_cuda(exc):
        return "CUDA was asked for (--device cuda) but this machine has no usable CUDA GPU; use --device cpu"
    name = type(exc).__name__
    if name == "SafetensorError" or "safetensors" in type(exc).__module__:
        return f"could not read the weights file: {exc} (is it a complete .safetensors written by cylindersplat?)"
    if "yaml" in type(exc).__module__:
        return f"malformed YAML: {text.splitlines()[0]}"
    return None


OUT_OF_MEMORY = ("out of memory: use a smaller resolution (--resolution / --output-resolution), fewer panoramas or "
                 "views at once, or another device (--device cuda, or a machine with more memory)")


def _os_error(exc: BaseException) -> OSError | None:
    """``exc`` if it is an ``OSError``, else an ``OSError`` with a storage errno it was raised from (libraries
    that wrap a full disk in their own exception), else None."""
    if isinstance(exc, OSError):
        return exc
    seen, cause = {id(exc)}, exc.__cause__ or exc.__context__
    while cause is not None and id(cause) not in seen:
        if isinstance(cause, OSError) and cause.errno in _STORAGE_ERRNOS:
            return cause
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
    match = re.search(r"os error (\d+)\)(?: at path \"([^\"]*)\")?", str(exc))  # safetensors' I/O errors
    if match and int(match.group(1)) in _STORAGE_ERRNOS:
        return OSError(int(match.group(1)), os.strerror(int(match.group(1))), match.group(2))
    return None


_STORAGE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.ENOMEM}


def _file_system_failure(exc: OSError) -> str | None:
    """The one line for an ``OSError`` a user can act on (full disk, permissions, a file in the way), else None."""
    path = os.fsdecode(exc.filename) if isinstance(exc.filename, (str, bytes, os.PathLike)) else None
    writing = f" while writing {path}" if path else ""
    if exc.errno == errno.ENOSPC:
        return f"disk full{writing}: free space or choose another --out"
    if exc.errno == errno.EDQUOT:
        return f"disk quota exceeded{writing}: free space or choose another --out"
    if exc.errno == errno.EFBIG:
        return f"file too large{writing} (a file-size limit: ulimit -f, FAT32's 4 GiB): choose another --out"
    if exc.errno == errno.EROFS:
        return f"read-only file system{' at ' + path if path else ''}: choose another --out"
    if exc.errno in (errno.EACCES, errno.EPERM):
        return (f"permission denied{' for ' + path if path else ''}: fix its permissions or choose a folder "
                "you can write to (--out)")
    if exc.errno == errno.ENOMEM:
        return OUT_OF_MEMORY
    if exc.errno in (errno.EEXIST, errno.ENOTDIR):
        blocker = _file_in_the_way(path) if path else None
        if blocker is None:
            return f"{exc.strerror}{f' ({path})' if path else ''}"
        for_path = f" (for {path})" if str(blocker) != path else ""
        return f"{blocker} is a file where a folder is needed{for_path}: choose another --out (or move the file away)"
    if exc.errno == errno.EISDIR:
        return f"{path or 'a path'} is a folder where a file is needed: give a file name"
    if isinstance(exc, FileNotFoundError):
        return str(exc)
    return None


def _file_in_the_way(path) -> Path | None:
    """The first part of ``path``, from the root down, that exists but is not a folder."""
    path = Path(os.fsdecode(path))
    for part in reversed([path, *path.parents]):
        if part.exists() and not part.is_dir():
            return part
    return None


def _no_cuda(exc: BaseException) -> bool:
    text = str(exc)
    return any(s in text for s in ("Torch not compiled with CUDA", "No CUDA GPUs are available",
                                   "Found no NVIDIA driver", "CUDA driver initialization failed"))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
