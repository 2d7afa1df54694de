"""Camera poses of 360° panoramas: other tools' files -> our OpenCV camera-to-world ``poses.json``, and SfM.

One module per tool, each opening with a table of what that tool means by a pose and by its panorama's pixels:

* :mod:`.conventions`: our conventions (the ``"convention"`` of a ``poses.json``), :class:`PoseRecord`, the checks;
* :mod:`.nerfstudio`, :mod:`.opensfm` (and OpenDroneMap), :mod:`.trajectories` (stella_vslam TUM/KITTI),
  :mod:`.colmap` (text and binary models, :mod:`.colmap_model`; equirectangular cameras and panorama rigs),
  :mod:`.metashape`, :mod:`.openmvg`: the readers (and writers), listed in :mod:`.registry`;
* :mod:`.poses_json`: writing our ``poses.json``;
* :mod:`.sfm` (poses of unposed panoramas with pycolmap), :mod:`.metric_scale` (metres per SfM unit),
  :mod:`.alignment` (how far estimated poses are from reference ones).
"""

from ...utils.lazy import lazy_exports

# Loaded at first use (:func:`cylindersplat.utils.lazy.lazy_exports`): the readers need torch, the registry's format
# names (``data import-poses --help``) do not.
__all__ = lazy_exports(__name__, globals(), {
    ".conventions": ("POSE_CONVENTIONS", "PoseRecord", "parse_pose_matrix", "to_opencv_c2w"),
    ".registry": ("POSE_FORMATS", "PoseFormat", "pose_format"),
    ".nerfstudio": ("EQUIRECT_CAMERA_MODELS", "is_transforms_json", "read_transforms_json"),
    ".opensfm": ("read_opensfm",),
    ".trajectories": ("read_tum", "read_kitti", "match_timestamps_to_images"),
    ".colmap": ("COLMAP_EQUIRECT_MODELS", "colmap_to_c2w", "c2w_to_colmap", "read_colmap", "write_colmap",
                "panoramas_from_virtual_cameras"),
    ".metashape": ("metashape_to_c2w", "read_metashape_xml", "write_metashape_xml"),
    ".openmvg": ("openmvg_to_c2w", "c2w_to_openmvg", "read_openmvg", "write_openmvg"),
    ".poses_json": ("write_poses_json",),
})
