"""CylinderSplat: feed-forward 3D Gaussian Splatting from posed 360-degree panoramas."""

__version__ = "0.1.0"
