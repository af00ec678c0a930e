"""Pinhole projection and pixel rays under the one pixel convention of bop-cender.

Convention (docs/design.md, "The pixel convention"): camera x right, y down, z forward; the centre of
pixel (row v, column u) is the continuous image point (u + 0.5, v + 0.5), as in the BOP toolkit's
renderer. A continuous image point is ``K @ p / p_z``; its pixel is ``floor`` of it. Projection itself
is the plain pinhole model (BOP's ``misc.project_pts``): the +0.5 only enters where pixels meet geometry.
"""

from __future__ import annotations

import numpy as np


def project_points(K: np.ndarray, points_cam: np.ndarray) -> np.ndarray:
    """Continuous image coordinates ``(..., N, 2)`` of camera-frame points ``(..., N, 3)``.

    No clipping, no distortion; points behind the camera project through the origin as in BOP.
    """
    K = np.asarray(K, dtype=np.float64)
    p = np.asarray(points_cam, dtype=np.float64) @ K.T
    return p[..., :2] / p[..., 2:3]


def pixel_centers(height: int, width: int) -> np.ndarray:
    """Continuous image coordinates ``(H, W, 2)`` of every pixel centre: ``(u + 0.5, v + 0.5)``."""
    v, u = np.meshgrid(np.arange(height, dtype=np.float64), np.arange(width, dtype=np.float64), indexing="ij")
    return np.stack([u + 0.5, v + 0.5], axis=-1)


def pixel_rays(K: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Unit camera-frame ray directions ``(..., 3)`` through continuous image points ``uv (..., 2)``.

    For pixel indices (u, v) pass ``uv = (u + 0.5, v + 0.5)`` (see :func:`pixel_centers`).
    """
    K_inv = np.linalg.inv(np.asarray(K, dtype=np.float64))
    uv = np.asarray(uv, dtype=np.float64)
    homog = np.concatenate([uv, np.ones((*uv.shape[:-1], 1))], axis=-1)
    d = homog @ K_inv.T
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def camera_center_in_world(T_cam_world: np.ndarray) -> np.ndarray:
    """Camera position ``(3,)`` in world coordinates, ``-R^T t``."""
    T = np.asarray(T_cam_world, dtype=np.float64)
    return -T[:3, :3].T @ T[:3, 3]


def rays_in_world(T_cam_world: np.ndarray, directions_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-frame ray origin ``(3,)`` and unit directions ``(..., 3)`` for camera-frame directions."""
    T = np.asarray(T_cam_world, dtype=np.float64)
    return camera_center_in_world(T), np.asarray(directions_cam, dtype=np.float64) @ T[:3, :3]
