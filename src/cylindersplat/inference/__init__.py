"""Inference on posed panoramas: read a user's folder, reconstruct Gaussians, render views and fly-throughs."""

from .camera_path import flythrough_path, interpolate_poses, midpoint_poses, slerp
from .inputs import PanoramaInputs, load_panorama_folder, read_poses_file, write_panorama_folder
from .pipeline import (
    depth_limits,
    normalized_depth,
    reconstruct_gaussians,
    render_views,
    view_picture,
    write_flythrough,
    write_view,
)
from .video import write_video

__all__ = [name for name in dir() if not name.startswith("_")]
