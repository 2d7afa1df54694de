"""Is a model hub id usable here, right now? Checked before a depth network is loaded from one.

The packages (``transformers``, ``unik3d``) fetch a hub id that is not cached with retries and back-off: offline,
that is a minute and a half of silence before a one-line error. :func:`check_hub_id` answers at once instead:
a cached id is fine (the packages read the cache); an uncached one needs the hub to answer a TCP connection
within a few seconds, else a ``FileNotFoundError`` says how to get the weights onto the machine.
"""

from __future__ import annotations

import os
import socket
from pathlib import Path
from urllib.parse import urlparse

__all__ = ["hub_cache_dir", "hub_cached", "hub_reachable", "check_hub_id"]

DEFAULT_ENDPOINT = "https://huggingface.co"
PROBE_SECONDS = 3.0


def hub_cache_dir() -> Path:
    """The Hugging Face hub cache: ``$HF_HUB_CACHE``, else ``$HF_HOME/hub``, else ``~/.cache/huggingface/hub``."""
    if os.environ.get("HF_HUB_CACHE"):
        return Path(os.environ["HF_HUB_CACHE"]).expanduser()
    home = os.environ.get("HF_HOME") or Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "huggingface"
    return Path(home).expanduser() / "hub"


def hub_cached(repo_id: str) -> bool:
    """A snapshot of model ``repo_id`` (``org/name``) is in the cache (the layout ``models--org--name/snapshots/*``)."""
    snapshots = hub_cache_dir() / f"models--{repo_id.replace('/', '--')}" / "snapshots"
    return snapshots.is_dir() and any(snapshots.iterdir())


def hub_reachable(timeout: float = PROBE_SECONDS) -> bool:
    """The hub (``$HF_ENDPOINT``, default huggingface.co) accepts a TCP connection within ``timeout`` seconds;
    never when ``HF_HUB_OFFLINE`` is set."""
    if os.environ.get("HF_HUB_OFFLINE", "").lower() in ("1", "true", "yes", "on"):
        return False
    url = urlparse(os.environ.get("HF_ENDPOINT") or DEFAULT_ENDPOINT)
    port = url.port or (80 if url.scheme == "http" else 443)
    try:
        with socket.create_connection((url.hostname, port), timeout=timeout):
            return True
    except OSError:
        return False


def check_hub_id(repo_id: str, prior: str) -> None:
    """Raise ``FileNotFoundError`` (one line, what to do) when ``repo_id`` is neither cached nor fetchable now."""
    if hub_cached(repo_id) or hub_reachable():
        return
    raise FileNotFoundError(
        f"depth prior {prior!r}: {repo_id!r} is a hub id that is not in the local cache ({hub_cache_dir()}) "
        "and the hub cannot be reached from here; download it where there is network "
        f"(e.g. `huggingface-cli download {repo_id} --local-dir DIR`) and give {prior}:DIR")
