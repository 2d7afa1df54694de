"""Panoramic geometry: equirect mapping, poses, rotations, triplane coordinate systems, cubemap cameras."""

from .cubemap import CUBEMAP_FACES, cubemap_face_c2w, cubemap_intrinsics, cubemap_rotations
from .equirect import (
    angles_to_uv,
    check_equirect_shape,
    equirect_jacobian,
    equirect_rays,
    pixel_centers,
    project_equirect,
    ray_to_uv,
    uv_to_angles,
    uv_to_ray,
)
from .poses import (
    camera_centers,
    camera_to_world,
    invert_rigid,
    look_at_c2w,
    make_c2w,
    transform_points,
    validate_c2w,
    world_to_camera,
)
from .rotations import matrix_to_quaternion, quaternion_multiply, quaternion_to_matrix
from .triplane_coords import (
    CartesianCoords,
    CylindricalCoords,
    SphericalCoords,
    TriplaneCoordinates,
    make_coordinates,
)

__all__ = [name for name in dir() if not name.startswith("_")]
