"""Square render windows around the projection of an object's origin (cost follows covered pixels).

A pose candidate is rendered only in an ``S x S`` window per (candidate, view), centred on the
projection of the model origin. ``S`` bounds the projection of the mesh's bounding sphere (radius ``r``
about the origin): a point of the sphere with centre ``(X, Y, Z)`` projects within
``f r sqrt(1 + (X/Z)^2) / (Z - r)`` pixels of the centre's projection along x (likewise y), which is
the renderer study's ``2 f r / z_min`` (docs/performance.md) with the off-axis factor that perspective
adds. Two pixels of margin on each side keep the curvature ring around the silhouette inside the window,
and ``S`` is rounded up to a multiple of 8.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch

#: Pixels kept between the bound on the object's projection and the window border, each side.
WINDOW_MARGIN = 3


def window_size(
    radius: float, T_cam_model: torch.Tensor, K: torch.Tensor, height: int, width: int, near: float = 1.0
) -> int:
    """Smallest multiple of 8 whose window holds the object in every (candidate, view).

    Args:
        radius: bounding-sphere radius of the mesh about its origin (mm).
        T_cam_model: ``(B, V, 4, 4)`` poses.
        K: ``(V, 3, 3)`` intrinsics.
        height, width: image size; the window never exceeds its larger side (rounded up to 8), which
            only matters for objects reaching the near plane.
        near: the near plane (mm).

    Returns:
        S.
    """
    cap = int(math.ceil(max(height, width) / 8.0) * 8)
    if T_cam_model.numel() == 0:
        return 8
    half = _half_extent(radius, T_cam_model, K, near)
    if not torch.isfinite(half).all():
        return cap
    size = 2.0 * float(half.max()) + 2 * WINDOW_MARGIN
    return min(cap, max(8, int(math.ceil(size / 8.0) * 8)))


def window_offsets(T_cam_model: torch.Tensor, K: torch.Tensor, size: int) -> torch.Tensor:
    """Window origins ``(B, V, 2)`` int64 (first row v0, first column u0) centred on the origin's projection.

    Args:
        T_cam_model: ``(B, V, 4, 4)`` poses.
        K: ``(V, 3, 3)`` intrinsics.
        size: S.
    """
    t = T_cam_model[..., :3, 3]
    z = t[..., 2].clamp_min(1e-6)
    x = (K[:, 0, 0] * t[..., 0] + K[:, 0, 1] * t[..., 1]) / z + K[:, 0, 2]
    y = K[:, 1, 1] * t[..., 1] / z + K[:, 1, 2]
    half = size // 2
    xy = torch.stack([y, x], -1).clamp(-1e7, 1e7)
    return torch.floor(xy).to(torch.int64) - half


def _half_extent(radius: float, T_cam_model: torch.Tensor, K: torch.Tensor, near: float) -> torch.Tensor:
    """Bound ``(B, V)`` in pixels on how far the object projects from its origin's projection (inf if it
    may reach the near plane)."""
    t = T_cam_model[..., :3, 3].to(torch.float64)
    K = K.to(torch.float64)
    z_min = t[..., 2] - radius
    a = t[..., 0] / t[..., 2].abs().clamp_min(1e-9)
    b = t[..., 1] / t[..., 2].abs().clamp_min(1e-9)
    fx = K[:, 0, 0] * torch.sqrt(1 + a * a) + K[:, 0, 1].abs() * torch.sqrt(1 + b * b)
    fy = K[:, 1, 1] * torch.sqrt(1 + b * b)
    half = radius * torch.maximum(fx, fy) / z_min.clamp_min(1e-9)
    return torch.where(z_min > near, half, torch.full_like(half, math.inf))


@dataclass(frozen=True)
class Windows:
    """Where each canvas's window lies in the image and in the flat pixel buffer.

    Canvas c covers image rows ``v0 .. v0 + rows[c] - 1`` and columns ``u0 .. u0 + width - 1``; its
    window pixel (i, j) is buffer element ``start[c] + i * width + j``. Uniform windows stack canvases
    of equal height; an *atlas* stacks windows of different heights and one width.

    Attributes:
        offsets: ``(C, 2)`` int64 image pixel (row v0, column u0) of each window's first pixel.
        rows: ``(C,)`` int64 window heights.
        start: ``(C,)`` int64 buffer index of each window's first pixel.
        width: common window width.
        total: buffer size (pixels).
    """

    offsets: torch.Tensor
    rows: torch.Tensor
    start: torch.Tensor
    width: int
    total: int

    @staticmethod
    def uniform(offsets: torch.Tensor, height: int, width: int) -> Windows:
        """C windows of ``height x width`` at ``offsets (C, 2)``, stacked."""
        C = int(offsets.shape[0])
        rows = torch.full((C,), height, dtype=torch.int64, device=offsets.device)
        start = torch.arange(C, device=offsets.device) * (height * width)
        return Windows(offsets.to(torch.int64), rows, start, width, C * height * width)

    @staticmethod
    def atlas(offsets: torch.Tensor, rows: torch.Tensor, width: int) -> Windows:
        """Windows of heights ``rows (C,)`` and one width, stacked one below the other."""
        rows = rows.to(torch.int64)
        ends = torch.cumsum(rows, 0)
        total = int(ends[-1]) * width if rows.numel() else 0
        return Windows(offsets.to(torch.int64), rows, (ends - rows) * width, width, total)

    @property
    def num_canvases(self) -> int:
        return int(self.offsets.shape[0])

    def table(self) -> torch.Tensor:
        """``(C, 4)`` int32: v0, u0, rows, start (what the scanline pass reads per triangle)."""
        return torch.stack([self.offsets[:, 0], self.offsets[:, 1], self.rows, self.start], 1).to(torch.int32)


def plan_atlas_chunks(extents: Sequence[Sequence[int]], chunk_pixels: int) -> list[tuple[int, int, int]]:
    """Greedy runs ``(start, stop, width)`` of windows ``extents (n, 2)`` (rows, columns; in order of width) whose
    atlas (:meth:`Windows.atlas`: stacked rows, the run's largest width) stays within ``chunk_pixels``; at least
    one window per run. Empty for no windows."""
    plan = []
    start, rows, w = 0, 0, 0
    for i, (eh, ew) in enumerate(extents):
        if i > start and (rows + eh) * max(w, ew) > chunk_pixels:
            plan.append((start, i, w))
            start, rows, w = i, 0, 0
        rows, w = rows + int(eh), max(w, int(ew))
    if len(extents):
        plan.append((start, len(extents), w))
    return plan
