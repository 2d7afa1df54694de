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

from .colmap import (
    COLMAP_EQUIRECT_MODELS,
    c2w_to_colmap,
    colmap_to_c2w,
    panoramas_from_virtual_cameras,
    read_colmap,
    write_colmap,
)
from .conventions import POSE_CONVENTIONS, PoseFormat, PoseRecord, parse_pose_matrix, to_opencv_c2w
from .metashape import metashape_to_c2w, read_metashape_xml, write_metashape_xml
from .nerfstudio import EQUIRECT_CAMERA_MODELS, is_transforms_json, read_transforms_json
from .openmvg import c2w_to_openmvg, openmvg_to_c2w, read_openmvg, write_openmvg
from .opensfm import read_opensfm
from .poses_json import write_poses_json
from .registry import POSE_FORMATS, pose_format
from .trajectories import match_timestamps_to_images, read_kitti, read_tum

__all__ = [
    "POSE_CONVENTIONS", "PoseRecord", "PoseFormat", "parse_pose_matrix", "to_opencv_c2w", "POSE_FORMATS", "pose_format",
    "EQUIRECT_CAMERA_MODELS", "is_transforms_json", "read_transforms_json", "read_opensfm", "read_tum", "read_kitti",
    "match_timestamps_to_images", "COLMAP_EQUIRECT_MODELS", "colmap_to_c2w", "c2w_to_colmap", "read_colmap",
    "write_colmap", "panoramas_from_virtual_cameras", "metashape_to_c2w", "read_metashape_xml", "write_metashape_xml",
    "openmvg_to_c2w", "c2w_to_openmvg", "read_openmvg", "write_openmvg", "write_poses_json",
]
