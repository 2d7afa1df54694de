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
    except (ValueError, FileNotFoundError) as exc:
        # User errors: one clear line, no traceback.
        print(f"cylindersplat {args.command}: error: {exc}", file=sys.stderr)
        return 1
    return int(result or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
