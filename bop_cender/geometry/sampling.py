"""Heatmap values at the projections of world points: what stage 2 maximises and stage 3's centre term reads.

Here, below both stages, so that neither imports the other for it (``centers`` uses the pose package's
simplex; the pose package reads heatmaps at pose centres).
"""

from __future__ import annotations

import numpy as np


def sample_scores(points: np.ndarray, heatmaps: np.ndarray, Ks: np.ndarray, T_cam_world: np.ndarray) -> np.ndarray:
    """Bilinearly sampled heatmap value ``(N, V)`` at the projection of world ``points (N, 3)`` in each of
    ``heatmaps (V, H, W)``; 0 behind the camera or outside the image (pixel centres at ``(u + 0.5, v + 0.5)``)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    V, H, W = heatmaps.shape
    p = np.einsum("vij,nj->vni", T_cam_world[:, :3, :3], points) + T_cam_world[:, None, :3, 3]  # (V, N, 3)
    z = p[..., 2]
    front = z > 1e-6
    zs = np.where(front, z, 1.0)
    x = (Ks[:, None, 0, 0] * p[..., 0] + Ks[:, None, 0, 1] * p[..., 1]) / zs + Ks[:, None, 0, 2] - 0.5
    y = Ks[:, None, 1, 1] * p[..., 1] / zs + Ks[:, None, 1, 2] - 0.5
    inside = front & (x >= -0.5) & (x <= W - 0.5) & (y >= -0.5) & (y <= H - 0.5)
    x = np.clip(x, 0, W - 1)
    y = np.clip(y, 0, H - 1)
    x0 = np.clip(np.floor(x).astype(np.int64), 0, W - 2 if W > 1 else 0)
    y0 = np.clip(np.floor(y).astype(np.int64), 0, H - 2 if H > 1 else 0)
    fx, fy = x - x0, y - y0
    x1, y1 = np.minimum(x0 + 1, W - 1), np.minimum(y0 + 1, H - 1)
    vi = np.arange(V)[:, None]
    val = (
        heatmaps[vi, y0, x0] * (1 - fx) * (1 - fy)
        + heatmaps[vi, y0, x1] * fx * (1 - fy)
        + heatmaps[vi, y1, x0] * (1 - fx) * fy
        + heatmaps[vi, y1, x1] * fx * fy
    )
    return np.where(inside, val, 0.0).T
