"""Data: one sample schema, dataset loaders, view protocols, depth priors, synthetic generator.

See ``docs/data.md`` for the on-disk layouts. The names below load from their modules at first use
(:func:`cylindersplat.utils.lazy.lazy_exports`): importing one light module of this package - the pose formats'
names, for ``data import-poses --help`` - imports no torch.
"""

from ..utils.lazy import lazy_exports

__all__ = lazy_exports(__name__, globals(), {
    ".base": ("ExampleRef", "FrameRef", "PanoramaDataset"),
    ".consistency": ("ConsistencyResult", "reprojection_consistency"),
    ".datasets": ("DATASETS", "make_dataset"),
    ".depth_prior": ("DepthPrior", "FilePrior", "GroundTruthPrior", "NoPrior", "SimulatedPrior",
                     "SimulatedPriorConfig", "make_depth_prior"),
    ".folder": ("FolderDataset",),
    ".io": ("read_depth_png", "read_rgb", "resize_depth", "write_depth_png", "write_rgb"),
    ".loc360": ("Loc360Dataset",),
    ".occlusion": ("occluded_fraction", "occluded_mask"),
    ".pano_grf": ("PanoGRFDataset", "panogrf_c2w"),
    ".sample": ("Sample", "collate_samples"),
    ".synthetic": ("SyntheticDataset",),
    ".views": ("ViewSplit", "all_between", "select_views"),
})
