"""Geometry: rigid transforms, projection and rays, rotations, BOP symmetries. Depends on nothing of ours."""

from bop_cender.geometry.camera import (
    camera_center_in_world,
    pixel_centers,
    pixel_rays,
    project_points,
    rays_in_world,
)
from bop_cender.geometry.poses import (
    c2w_to_w2c,
    compose,
    invert_pose,
    make_pose,
    pose_from_bop,
    pose_residual,
    transform_points,
    w2c_to_c2w,
)
from bop_cender.geometry.rotations import (
    axis_angle_to_rotmat,
    orthonormality_error,
    quat_to_rotmat,
    random_rotations,
    rotation_angle,
    rotmat_to_quat,
    rotmat_to_rotvec,
    rotvec_to_rotmat,
)
from bop_cender.geometry.symmetry import (
    BOP19_MAX_SYM_DISC_STEP,
    ContinuousSymmetry,
    apply_symmetries_to_pose,
    continuous_step_count,
    symmetries_from_model_info,
    symmetry_transforms,
)

__all__ = [
    "BOP19_MAX_SYM_DISC_STEP",
    "ContinuousSymmetry",
    "apply_symmetries_to_pose",
    "axis_angle_to_rotmat",
    "c2w_to_w2c",
    "camera_center_in_world",
    "compose",
    "continuous_step_count",
    "invert_pose",
    "make_pose",
    "orthonormality_error",
    "pixel_centers",
    "pixel_rays",
    "pose_from_bop",
    "pose_residual",
    "project_points",
    "quat_to_rotmat",
    "random_rotations",
    "rays_in_world",
    "rotation_angle",
    "rotmat_to_quat",
    "rotmat_to_rotvec",
    "rotvec_to_rotmat",
    "symmetries_from_model_info",
    "symmetry_transforms",
    "transform_points",
    "w2c_to_c2w",
]
