"""Small shared utilities (colormaps, allocator tuning, ...)."""
