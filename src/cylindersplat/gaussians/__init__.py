"""Gaussian container, standard 3DGS PLY I/O and the other splat formats (:mod:`.formats`)."""

from .container import SH_C0, Gaussians, rgb_to_sh0, sh0_to_rgb, sh_degree_from_count
from .formats import load_gaussians, save_gaussians
from .ply import load_ply, save_ply
from .splat import save_splat

__all__ = ["Gaussians", "SH_C0", "rgb_to_sh0", "sh0_to_rgb", "sh_degree_from_count", "load_ply", "save_ply",
           "save_splat",
           "load_gaussians", "save_gaussians"]
