"""Moved to :mod:`cylindersplat.data.pose_formats` (the one module of pose conventions); this name still works."""

from ..data.pose_formats import *  # noqa: F401,F403
from ..data.pose_formats import __all__  # noqa: F401
