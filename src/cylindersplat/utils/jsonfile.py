"""JSON files in and out. In: :func:`read_json_file`, every input JSON file's reader (one line for a missing,
undecodable or absurdly nested file instead of a traceback). Out: strict JSON text for result files:
``json.dumps`` writes ``inf`` / ``nan`` as ``Infinity`` / ``NaN``, which most JSON parsers (JavaScript, jq, Go, ...)
refuse. Result files write them as ``null`` instead;
where a value is infinite on purpose (a PSNR of a render equal to its target) the file's notes say so."""

from __future__ import annotations

import json
import math
from typing import Any

__all__ = ["strict_json", "json_text", "read_json_file"]


def strict_json(value: Any) -> Any:
    """``value`` with every non-finite float (in nested dicts, lists and tuples) replaced by ``None``."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: strict_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [strict_json(v) for v in value]
    return value


def json_text(value: Any, indent: int | None = 1) -> str:
    """JSON text any parser reads (``allow_nan=False`` after :func:`strict_json`)."""
    return json.dumps(strict_json(value), indent=indent, allow_nan=False)


def read_json_file(path, what: str = "file") -> Any:
    """The parsed JSON of ``path``; ``FileNotFoundError`` (``missing {what}: path``) or ``ValueError`` naming the
    file for text that is not JSON, not UTF-8, or nested too deeply to parse (a hostile file)."""
    from pathlib import Path

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"missing {what}: {path}")
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None
    except RecursionError:
        raise ValueError(f"{path}: JSON nested too deeply to read "
                         "(thousands of levels); is it the right file?") from None
