"""Rigid transforms as 4x4 homogeneous float64 arrays, named by their frames.

``T_b_a`` maps points from frame ``a`` into frame ``b``: ``p_b = T_b_a @ p_a``. So
``T_cam_model = T_cam_world @ T_world_model``. All translations are millimetres.
Functions accept a single transform ``(4, 4)`` or a stack ``(..., 4, 4)``.
"""

from __future__ import annotations

import numpy as np


def make_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Build ``(..., 4, 4)`` transforms from rotations ``(..., 3, 3)`` and translations ``(..., 3)``."""
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64).reshape(*R.shape[:-2], 3)
    T = np.zeros((*R.shape[:-2], 4, 4), dtype=np.float64)
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def pose_from_bop(R_flat, t) -> np.ndarray:
    """A 4x4 transform from BOP's row-major 9-list ``R`` and 3-list ``t`` (mm)."""
    return make_pose(np.asarray(R_flat, dtype=np.float64).reshape(3, 3), np.asarray(t, dtype=np.float64))


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms ``(..., 4, 4)``: ``[R^T | -R^T t]`` (exact, no general inverse)."""
    T = np.asarray(T, dtype=np.float64)
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    Rt = np.swapaxes(R, -1, -2)
    return make_pose(Rt, -np.einsum("...ij,...j->...i", Rt, t))


def compose(*transforms: np.ndarray) -> np.ndarray:
    """Product of transforms left to right: ``compose(T_c_b, T_b_a) == T_c_a``."""
    if not transforms:
        raise ValueError("compose needs at least one transform")
    out = np.asarray(transforms[0], dtype=np.float64)
    for T in transforms[1:]:
        out = out @ np.asarray(T, dtype=np.float64)
    return out


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply ``T (4, 4)`` to ``points (N, 3)``, or a stack ``T (B, 4, 4)`` to give ``(B, N, 3)``."""
    T = np.asarray(T, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64)
    return points @ np.swapaxes(T[..., :3, :3], -1, -2) + T[..., None, :3, 3]


def c2w_to_w2c(T_world_cam: np.ndarray) -> np.ndarray:
    """Camera-to-world (DIMO's ``cam_R_c2w``/``cam_t_c2w``) to world-to-camera ``T_cam_world``."""
    return invert_pose(T_world_cam)


def w2c_to_c2w(T_cam_world: np.ndarray) -> np.ndarray:
    """World-to-camera ``T_cam_world`` to camera-to-world ``T_world_cam``."""
    return invert_pose(T_cam_world)


def pose_residual(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """Difference of two transforms: (translation distance in mm, rotation angle in radians).

    The angle is ``atan2(|skew(dR)|, (tr(dR) - 1) / 2)``, exact for rotations and, unlike
    ``arccos`` of the trace, not inflated near zero by files that round R to 6 digits (an
    ``arccos`` reads a 1e-6 non-orthonormality as ~1e-3 rad).
    """
    dt = float(np.linalg.norm(np.asarray(T_a)[:3, 3] - np.asarray(T_b)[:3, 3]))
    dR = np.asarray(T_a)[:3, :3].T @ np.asarray(T_b)[:3, :3]
    sin = 0.5 * np.linalg.norm([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]])
    cos = (np.trace(dR) - 1.0) / 2.0
    return dt, float(np.arctan2(sin, cos))
