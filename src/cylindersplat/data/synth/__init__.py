"""Procedural panoramic scene generator (CPU): exact ray casting of textured primitives.

Modules: :mod:`.scene` (primitives), :mod:`.materials` (textures, shading), :mod:`.raycast`
(intersections, equirect rendering), :mod:`.layouts` (random rooms / outdoor scenes),
:mod:`.sequence` (camera lines), :mod:`.writer` (on-disk layout).
"""

from .layouts import LAYOUTS, add_occluders, indoor_scene, outdoor_scene, random_scene
from .materials import Lighting, Material, Sky
from .raycast import cast_rays, render_equirect_scene
from .scene import SceneBuilder, SynthScene
from .sequence import (
    PROFILES,
    SequenceConfig,
    SynthSequence,
    camera_path,
    generate_sequence,
    profile_config,
    render_sequence,
    sample_camera_line,
    scene_rng,
    target_offset,
)
from .writer import SYNTH_FORMAT, config_record, scene_id, write_synthetic_dataset

__all__ = [name for name in dir() if not name.startswith("_")]
