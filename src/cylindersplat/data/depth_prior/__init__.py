"""Depth priors for the context views: files, networks, simulated, ground truth, constant, none."""

from .adapters import (
                       DepthAnythingV2Adapter,
                       ExportedDepthPrior,
                       FoundationDepthAdapter,
                       NetworkDepthPrior,
                       UniK3DAdapter,
                       file_sha256,
)
from .base import (
                       MISSING_PRIOR_HELP,
                       ConstantPrior,
                       DepthPrior,
                       GroundTruthPrior,
                       MissingPrior,
                       NoPrior,
                       PriorQuery,
                       StoredDepthPrior,
)
from .files import PRIORS_DIR, SIDECAR, FilePrior, prior_tree, read_sidecar, tree_file
from .registry import (
                       DEPTH_PRIORS,
                       NETWORK_PRIORS,
                       make_depth_prior,
                       parse_depth_prior,
                       parse_network_prior,
                       register_depth_prior,
                       require_depth_prior,
)
from .simulated import SimulatedPrior, SimulatedPriorConfig, degrade_depth

__all__ = [name for name in dir() if not name.startswith("_")]
