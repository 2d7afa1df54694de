"""The ``cylindersplat`` command line.

Each subcommand lives in its own module exposing ``register(subparsers)``, which adds an argparse
sub-parser whose ``func`` attribute runs the command with the parsed namespace. Add a subcommand by
adding a module to ``cylindersplat/commands/``: every module there is registered, in name order.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys


def subcommand_modules() -> list[str]:
    """Every module of ``cylindersplat.commands`` (those starting with ``_`` are helpers)."""
    from . import commands

    names = sorted(m.name for m in pkgutil.iter_modules(commands.__path__) if not m.name.startswith("_"))
    return [f"{commands.__name__}.{name}" for name in names]


def build_parser() -> argparse.ArgumentParser:
    from . import __version__

    parser = argparse.ArgumentParser(
        prog="cylindersplat",
        description="Feed-forward 3D Gaussian Splatting from posed 360-degree panoramas.",
    )
    parser.add_argument("--version", action="version", version=f"cylindersplat {__version__}")
    parser.add_argument("--debug", action="store_true", help="show the full traceback of an error")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module in subcommand_modules():
        importlib.import_module(module).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    from .utils.allocator import keep_freed_memory

    parser = build_parser()
    args = parser.parse_args(argv)
    keep_freed_memory()  # the CPU renderer reuses large buffers (see utils.allocator)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        result = args.func(args)
    except KeyboardInterrupt:
        print(f"cylindersplat {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - sorted into expected failures and bugs below
        message = None if args.debug else expected_failure(exc)
        if message is None:
            raise  # a bug (or --debug): the traceback is what we need
        # Expected failures: one clear line, no traceback.
        print(f"cylindersplat {args.command}: error: {message}", file=sys.stderr)
        return 1
    return int(result or 0)


def expected_failure(exc: BaseException) -> str | None:
    """One line for failures a user can fix (bad input, missing files or packages, no CUDA, full disk,
    out of memory); ``None`` for anything else, which is a bug and keeps its traceback."""
    import errno

    import torch

    if isinstance(exc, MemoryError) and str(exc):  # our own estimate before allocating, with its numbers
        return str(exc)
    if isinstance(exc, torch.OutOfMemoryError):
        return ("out of memory; use a smaller resolution or fewer views/cameras at once, or a machine with more "
                f"memory ({str(exc).splitlines()[0][:200]})")
    if isinstance(exc, OSError) and not isinstance(exc, FileNotFoundError):
        where = f" ({exc.filename})" if getattr(exc, "filename", None) else ""
        if exc.errno == errno.ENOSPC:
            return f"disk full{where}; free space or write somewhere else (--out)"
        if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
            return f"permission denied{where}; choose a folder you can write to"
        if exc.errno in (errno.EISDIR, errno.ENOTDIR, errno.EEXIST):
            return f"{exc.strerror}{where}"
        if exc.errno == errno.EFBIG:
            return f"file too large{where}"
        return None
    if isinstance(exc, (ValueError, FileNotFoundError)):
        return str(exc)
    if isinstance(exc, ModuleNotFoundError):
        return f"the optional package {exc.name!r} is not installed ({exc}); install it with pip"
    if isinstance(exc, (AssertionError, RuntimeError)) and _no_cuda(exc):
        return "CUDA was asked for (--device cuda) but this machine has no usable CUDA GPU; use --device cpu"
    name = type(exc).__name__
    if name == "SafetensorError" or "safetensors" in type(exc).__module__:
        return f"could not read the weights file: {exc} (is it a complete .safetensors written by cylindersplat?)"
    if "yaml" in type(exc).__module__:
        return f"malformed YAML: {str(exc).splitlines()[0]}"
    return None


def _no_cuda(exc: BaseException) -> bool:
    text = str(exc)
    return any(s in text for s in ("Torch not compiled with CUDA", "No CUDA GPUs are available",
                                   "Found no NVIDIA driver", "CUDA driver initialization failed"))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
