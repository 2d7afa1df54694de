"""Non-learned reference methods, evaluated like the model (same inputs, same outputs)."""

from .forward_warp import forward_warp, nearest_source

__all__ = ["forward_warp", "nearest_source"]
