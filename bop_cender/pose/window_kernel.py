"""The scene polish's windowed cost after the render, as one compiled loop per canvas (CPU).

Why. :meth:`~bop_cender.pose.scene_polish.SceneWindow.costs` renders the moving part into its windows, then
composites it over the other parts by depth, takes the curvature of the composite normals
(:func:`~bop_cender.render.curvature.curvature`), the forward cost (:func:`~bop_cender.pose.cost.view_costs`)
and the backward one (:func:`~bop_cender.pose.coverage.mean_distance_to_own_edges`). In torch those steps are
about 40 operators over ``(V, h, w)`` arrays, 7 of 12 ms of a call on one CPU thread (``scripts/bench_run.py``,
"Scene polish"), and the scene polish makes about 70 calls per part. Here the composite, the curvature, the
forward sums and the binarised own edges are one pass over each canvas's pixels; the own edges' distance
transform stays OpenCV's (:func:`~bop_cender.pose.cost.distance_map`), and the backward mean is taken from it.

Same arithmetic as the torch steps, in float32 for the curvature (the renderer's
:func:`~bop_cender.render.compiled_raster.pixel_curvature`, with torch's multiply-add rounding as probed, so the
binarisation at the edge threshold sees the same values) and float64 for the sums: the costs agree to float32 rounding
(``tests/pose/test_scene_polish.py``).
"""

from __future__ import annotations

import math

import numba
import numpy as np
import torch

from bop_cender.pose.cost import distance_map
from bop_cender.render.compiled_raster import ADDCMUL_FUSED, pixel_curvature
from bop_cender.render.numba_loops import as_numpy as _np
from bop_cender.render.numba_loops import canvas_loop


@canvas_loop
def _composite_costs(depth, normals, other_depth, other_normals, dist, offsets, threshold, fused, forward,
                     own_edges):  # fmt: skip
    """Per canvas c (view ``c % V``): the forward cost into ``forward[c]`` and the composite's own edges (1 where
    its curvature exceeds ``threshold``) into ``own_edges[c]``; returns the number of own-edge pixels per canvas."""
    N, h, w = depth.shape
    V, H, W = dist.shape
    diagonal = math.hypot(H, W)
    edge_count = np.zeros(N, dtype=np.int64)
    has_other = other_depth.shape[0] > 0
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
                    own_edges[c, i, j] = 1
                    edges += 1
                else:
                    own_edges[c, i, j] = 0
        forward[c] = num / den if den > 0.0 else diagonal
        edge_count[c] = edges
    return edge_count


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
    forward = np.empty(N, dtype=np.float64)
    own_edges = np.empty((N, h, w), dtype=np.bool_)
    if other_depth is None or other_normals is None:  # no rows: nothing to composite with
        other = (np.zeros((0, 1, 1), np.float32), np.zeros((0, 1, 1, 3), np.float32))
    else:
        other = (_np(other_depth), _np(other_normals))
    counts = _composite_costs(
        _np(depth),
        _np(normals),
        *other,
        _np(dist),
        _np(offsets),
        np.float32(edge_threshold),
        bool(ADDCMUL_FUSED),
        forward,
        own_edges,
    )
    targets = _np(target_edges).astype(bool, copy=False)  # a 0/1 mask of any dtype selects pixels, as in torch
    V = targets.shape[0]
    backward = np.zeros(N, dtype=np.float64)
    for c in range(N):
        pixels = targets[c % V]
        n_pixels = int(np.count_nonzero(pixels))
        if n_pixels == 0:
            continue
        if counts[c] == 0:
            backward[c] = np.float32(math.hypot(h, w))  # no own edge: every pixel at the window's diagonal
            continue
        own = distance_map(own_edges[c])
        backward[c] = float(own[pixels].sum(dtype=np.float64)) / n_pixels
    return torch.from_numpy(forward + backward)
