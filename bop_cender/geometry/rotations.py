"""Rotation conversions (matrix, rotation vector, quaternion), random rotations, validity checks.

Thin, named wrappers over ``scipy.spatial.transform.Rotation`` so the representation is in the
name (``rotvec_to_rotmat``). Quaternions are scalar-last ``(x, y, z, w)``, scipy's convention.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def rotvec_to_rotmat(rotvec: np.ndarray) -> np.ndarray:
    """Rotation vectors ``(..., 3)`` (axis * angle, radians) to matrices ``(..., 3, 3)``."""
    rv = np.asarray(rotvec, dtype=np.float64)
    return Rotation.from_rotvec(rv.reshape(-1, 3)).as_matrix().reshape(*rv.shape[:-1], 3, 3)


def rotmat_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` to rotation vectors ``(..., 3)``."""
    R = np.asarray(R, dtype=np.float64)
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(*R.shape[:-2], 3)


def quat_to_rotmat(quat_xyzw: np.ndarray) -> np.ndarray:
    """Quaternions ``(..., 4)`` scalar-last to matrices ``(..., 3, 3)`` (normalised first)."""
    q = np.asarray(quat_xyzw, dtype=np.float64)
    return Rotation.from_quat(q.reshape(-1, 4)).as_matrix().reshape(*q.shape[:-1], 3, 3)


def rotmat_to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` to unit quaternions ``(..., 4)``, scalar-last, w >= 0."""
    R = np.asarray(R, dtype=np.float64)
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat(canonical=True)
    return q.reshape(*R.shape[:-2], 4)


def axis_angle_to_rotmat(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation ``(3, 3)`` by ``angle`` radians about ``axis`` (normalised here)."""
    axis = np.asarray(axis, dtype=np.float64)
    return rotvec_to_rotmat(axis / np.linalg.norm(axis) * angle)


def random_rotations(n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` rotations ``(n, 3, 3)`` uniform on SO(3) (Haar measure), from an explicit generator."""
    return Rotation.random(n, random_state=rng).as_matrix().reshape(n, 3, 3)


def orthonormality_error(R: np.ndarray) -> np.ndarray:
    """Max abs entry of ``R R^T - I`` per matrix ``(...,)``: 0 for an exact rotation."""
    R = np.asarray(R, dtype=np.float64)
    eye = np.eye(3)
    return np.abs(R @ np.swapaxes(R, -1, -2) - eye).max(axis=(-1, -2))


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Angle in radians ``(...,)`` of rotations ``(..., 3, 3)``."""
    R = np.asarray(R, dtype=np.float64)
    cos = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.arccos(np.clip(cos, -1.0, 1.0))
