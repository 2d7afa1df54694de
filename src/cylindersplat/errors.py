"""The library's error types: what a caller can fix, as ``ValueError`` subclasses.

Every public entry (the CLI's commands, :func:`~cylindersplat.inference.reconstruct_gaussians`,
:func:`~cylindersplat.render.render_equirect`, the dataset readers) refuses bad input with an
:class:`InputError` whose message is one line: the value, where it came from, and what to do. The CLI
prints that line (``cylindersplat CMD: error: ...``) instead of a traceback; Python callers can catch
``InputError`` (or plain ``ValueError``).
"""

from __future__ import annotations

__all__ = ["InputError", "OutsideFolderError", "ImplausibleInputError"]


class InputError(ValueError):
    """An input (argument, tensor, file) that the library refuses; the message says what and how to fix it."""


class OutsideFolderError(InputError):
    """A file named by an input file (``poses.json``, ``transforms.json``) lies outside the input's folder."""


class ImplausibleInputError(InputError):
    """A finite value outside the documented plausibility bounds (e.g. depth beyond 1 km)."""
