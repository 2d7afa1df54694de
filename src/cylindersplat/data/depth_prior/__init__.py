"""Depth priors for the context views: none, ground truth, simulated, files, foundation models."""

from .adapters import DepthAnywhereAdapter, FoundationDepthAdapter, ExportedDepthPrior, UniFuseAdapter, UniK3DAdapter
from .base import ConstantPrior, DepthPrior, GroundTruthPrior, NoPrior, PriorQuery
from .files import FilePrior
from .registry import DEPTH_PRIORS, make_depth_prior, parse_depth_prior, register_depth_prior, require_depth_prior
from .simulated import SimulatedPrior, SimulatedPriorConfig, degrade_depth

__all__ = [name for name in dir() if not name.startswith("_")]
