"""Data: one sample schema, dataset loaders, view protocols, depth priors, synthetic generator.

See ``docs/data.md`` for the on-disk layouts.
"""

from .base import ExampleRef, FrameRef, PanoramaDataset
from .consistency import ConsistencyResult, reprojection_consistency
from .datasets import DATASETS, make_dataset
from .depth_prior import (
    DepthPrior,
    FilePrior,
    GroundTruthPrior,
    NoPrior,
    SimulatedPrior,
    SimulatedPriorConfig,
    make_depth_prior,
)
from .folder import FolderDataset
from .io import read_depth_png, read_rgb, resize_depth, write_depth_png, write_rgb
from .loc360 import Loc360Dataset
from .occlusion import occluded_fraction, occluded_mask
from .pano_grf import PanoGRFDataset, panogrf_c2w
from .sample import Sample, collate_samples
from .synthetic import SyntheticDataset
from .views import ViewSplit, all_between, select_views

__all__ = [name for name in dir() if not name.startswith("_")]
