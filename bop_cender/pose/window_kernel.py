"""The scene polish's windowed cost after the render, as one compiled loop per canvas (CPU).

Why. :meth:`~bop_cender.pose.backend.Backend.window_costs` renders the moving part into its windows, then
composites it over the other parts by depth, takes the curvature of the composite normals
(:func:`~bop_cender.render.curvature.curvature`), the forward cost (:func:`~bop_cender.pose.cost.view_costs`)
and the backward one (:func:`~bop_cender.pose.coverage.mean_distance_to_own_edges`). In torch those steps are
about 40 operators over ``(V, h, w)`` arrays, 7 of 12 ms of a call on one CPU thread (``scripts/bench_run.py``,
"Scene polish"), and the scene polish makes about 70 calls per part. Here the composite, the curvature, the
forward sums and the binarised own edges are one pass over each canvas's pixels, and the backward term follows in
the same loop: each row's distance to its nearest own edge, then at each target pixel the least
``g(k, j)^2 + (i - k)^2`` over the rows (:func:`row_distances`, :func:`nearest_edge_sq`, shared with the CUDA kernel
of :mod:`bop_cender.pose.cuda_window_kernel`). That is the exact Euclidean distance, read only where the backward
term reads it, without a transform of the window and without a Python loop over the canvases (it was OpenCV's
precise transform per canvas; the two agree but for OpenCV's last float32 bit of some distances).

Same arithmetic as the torch steps, in float32 for the curvature (the renderer's
:func:`~bop_cender.render.compiled_raster.pixel_curvature`, with torch's multiply-add rounding as probed, so the
binarisation at the edge threshold sees the same values) and float64 for the sums: the costs agree to float32 rounding
(``tests/pose/test_scene_polish.py``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numba
import numpy as np
import torch

from bop_cender.render.compiled_raster import ADDCMUL_FUSED, pixel_curvature, sqrt32
from bop_cender.render.numba_cache import cached_njit
from bop_cender.render.numba_loops import as_numpy as _np
from bop_cender.render.numba_loops import canvas_loop


class DistanceArithmetic(NamedTuple):
    """The backward term's exact distances compiled for one target (:func:`distance_arithmetic`)."""

    row_distances: Callable
    nearest_edge_sq: Callable


def distance_arithmetic(jit: Callable) -> DistanceArithmetic:
    """The backward term's distance steps compiled by ``jit``: numba's CPU ``njit`` (inlined in the CPU loop), numba's
    CUDA ``jit(device=True)`` (:mod:`bop_cender.pose.cuda_window_kernel`), or the identity (numba's CUDA simulator):
    one source for both targets."""

    @jit
    def row_distances(g, base, w):
        """Row ``g[base : base + w]`` (0 at an own edge, a large value elsewhere) to each pixel's distance to its row's
        nearest own edge, in place (pixels of a row without an edge keep the large value): a sweep each way."""
        last = -1
        for j in range(w):
            if g[base + j] == 0:
                last = j
            elif last >= 0:
                g[base + j] = j - last
        nxt = -1
        for j in range(w - 1, -1, -1):
            if g[base + j] == 0:
                nxt = j
            elif nxt >= 0 and nxt - j < g[base + j]:
                g[base + j] = nxt - j

    @jit
    def nearest_edge_sq(g, i, j, h, w, far):
        """The squared Euclidean distance from pixel ``(i, j)`` to the nearest own edge, from the row distances ``g``
        (flat, row-major, :func:`row_distances`): the least ``g[k, j]^2 + (i - k)^2`` over the rows ``k`` (``far^2``
        where there is none)."""
        best = far * far
        for k in range(h):
            gk = g[k * w + j]
            d2 = gk * gk + (i - k) * (i - k)
            if d2 < best:
                best = d2
        return best

    return DistanceArithmetic(row_distances, nearest_edge_sq)


#: The steps compiled for the CPU, inlined where they are called.
CPU_ARITHMETIC = distance_arithmetic(cached_njit(nogil=True, inline="always"))
row_distances = CPU_ARITHMETIC.row_distances
nearest_edge_sq = CPU_ARITHMETIC.nearest_edge_sq


@canvas_loop
def _composite_costs(depth, normals, other_depth, other_normals, dist, offsets, targets, threshold, fused, total):
    """Per canvas c (view ``c % V``): forward plus backward cost into ``total[c]``."""
    N, h, w = depth.shape
    V, H, W = dist.shape
    diagonal = math.hypot(H, W)
    has_other = other_depth.shape[0] > 0
    far = 2 * (h + w)
    for c in numba.prange(N):
        v = c % V
        comp = np.empty((h, w, 3), dtype=np.float32)
        for i in range(h):
            for j in range(w):
                d = depth[c, i, j]
                o = other_depth[v, i, j] if has_other else 0.0
                for k in range(3):
                    if d > 0 and (o == 0 or d < o):
                        comp[i, j, k] = normals[c, i, j, k]
                    else:
                        comp[i, j, k] = other_normals[v, i, j, k] if has_other else 0.0
        top, left = offsets[v, 0], offsets[v, 1]
        num = 0.0
        den = 0.0
        edges = 0
        g = np.empty(h * w, dtype=np.int64)  # 0 at an own edge, then each pixel's distance to its row's nearest
        for i in range(h):
            i0, i2 = max(i - 1, 0), min(i + 1, h - 1)
            for j in range(w):
                j0, j2 = max(j - 1, 0), min(j + 1, w - 1)
                curv = pixel_curvature(comp, i0, i, i2, j0, j, j2, fused)  # curvature's replicated border
                r, s = top + i, left + j
                if 0 <= r < H and 0 <= s < W:
                    num += np.float64(curv) * np.float64(dist[v, r, s])
                    den += np.float64(curv)
                if curv > threshold:
                    g[i * w + j] = 0
                    edges += 1
                else:
                    g[i * w + j] = far
        for i in range(h):
            row_distances(g, i * w, w)
        n_targets = 0
        backward = 0.0
        for i in range(h):
            for j in range(w):
                if targets[v, i, j]:
                    n_targets += 1
                    if edges > 0:
                        backward += np.float64(sqrt32(np.float32(nearest_edge_sq(g, i, j, h, w, far))))
        if n_targets > 0:
            backward = backward / n_targets if edges > 0 else np.float64(np.float32(math.hypot(h, w)))
        total[c] = (num / den if den > 0.0 else diagonal) + backward


def window_costs(
    depth: torch.Tensor,
    normals: torch.Tensor,
    other_depth: torch.Tensor | None,
    other_normals: torch.Tensor | None,
    dist: torch.Tensor,
    offsets: torch.Tensor,
    target_edges: torch.Tensor,
    edge_threshold: float,
) -> torch.Tensor:
    """Forward plus backward cost ``(N,)`` float64 of N canvases (canvas c in view ``c % V``), CPU tensors.

    Args:
        depth, normals: ``(N, h, w)``, ``(N, h, w, 3)`` the moving part's render in the windows.
        other_depth, other_normals: ``(V, h, w)``, ``(V, h, w, 3)`` the other parts there (depth 0: none); None:
            nothing else in the windows (the full scene cost: every part is in ``depth`` already).
        dist: ``(V, H, W)`` the target's full distance maps; ``offsets (V, 2)`` each view's window origin (row,
            column).
        target_edges: ``(V, h, w)`` bool, the target edges the backward term measures.
        edge_threshold: raw curvature above which a composite pixel is one of its own edges.
    """
    N, h, w = depth.shape
    total = np.empty(N, dtype=np.float64)
    if other_depth is None or other_normals is None:  # no rows: nothing to composite with
        other = (np.zeros((0, 1, 1), np.float32), np.zeros((0, 1, 1, 3), np.float32))
    else:
        other = (_np(other_depth), _np(other_normals))
    targets = _np(target_edges).astype(bool, copy=False)  # a 0/1 mask of any dtype selects pixels, as in torch
    _composite_costs(_np(depth), _np(normals), *other, _np(dist), _np(offsets), targets, np.float32(edge_threshold),
                     bool(ADDCMUL_FUSED), total)  # fmt: skip
    return torch.from_numpy(total)
