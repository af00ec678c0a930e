"""The render-and-compare cost of pose candidates as one compiled loop per canvas (CPU).

Why. :meth:`~bop_cender.pose.backend.Backend.candidate_costs` renders every (candidate, view) canvas in a tight window
(:mod:`bop_cender.render.candidate_curvature`), takes the Prewitt curvature of its normals and sums it against
the view's distance map: in torch, a few hundred operators per chunk of canvases, with the windows stacked
into atlases so that the operators amortise. Here each canvas is rendered by the compiled rasteriser
(:func:`bop_cender.render.compiled_raster.raster_window`, the torch pipeline's bits), hidden behind the placed
objects, and its curvature and both sums are taken in the same pass, with no atlas and no operator overhead.

Same windows (``prepare_candidates``), the same occlusion rule (:func:`~bop_cender.render.candidate_curvature.
occluded`), the first and last window rows forced to background as in the atlas, the curvature of
:func:`~bop_cender.render.curvature.curvature_valid` with torch's multiply-adds. The sums are float64 here (torch
reduces float32 in its own order), so the costs agree with the torch path to float32 rounding, not bit for bit
(``tests/pose/test_cost_kernel.py``).
"""

from __future__ import annotations

import math

import numba
import numpy as np
import torch

from bop_cender.render.candidate_curvature import OCCLUSION_MARGIN_MM, CandidateBatch
from bop_cender.render.compiled_raster import loop_inputs, pixel_curvature, raster_window
from bop_cender.render.numba_loops import as_numpy as _np
from bop_cender.render.numba_loops import canvas_loop


@canvas_loop(error_model="numpy")
def _canvas_costs(cam_all, px_all, py_all, draw, faces, face_instance, corner_normals, R, K_inv, face_bits,
                  depth_bits, fused, lo, extent, near, occ, margin, dist, out):  # fmt: skip
    """Unweighted cost of each canvas ``c`` (view ``c % V``) into ``out[c]`` (the first twelve arguments:
    :func:`~bop_cender.render.compiled_raster.loop_inputs`)."""
    V, H, W = dist.shape
    diagonal = np.float32(math.hypot(H, W))
    has_occ = occ.shape[0] > 0
    for c in numba.prange(R.shape[0]):
        v = c % V
        top, left = lo[c, 0], lo[c, 1]
        h, w = extent[c, 0], extent[c, 1]
        depth = np.zeros((h, w), dtype=np.float32)
        normals = np.zeros((h, w, 3), dtype=np.float32)
        faces_hit = np.full((h, w), -1, dtype=np.int64)
        raster_window(cam_all[c], px_all[c], py_all[c], draw[c], faces, face_instance, corner_normals, R[c], K_inv[c],
                      top, left, h, w, near, face_bits, depth_bits, fused, depth, normals, faces_hit)  # fmt: skip
        if has_occ:  # candidate_curvature._hide_occluded: hidden pixels become background
            for i in range(h):
                r = top + i
                if r < 0 or r >= H:
                    continue
                for j in range(w):
                    s = left + j
                    if s < 0 or s >= W:
                        continue
                    o = occ[v, r, s]
                    d = depth[i, j]
                    if o > 0 and d > 0 and d > o - margin:
                        normals[i, j, 0] = 0.0
                        normals[i, j, 1] = 0.0
                        normals[i, j, 2] = 0.0
        for j in range(w):  # the first and last rows of a window are background (the atlas rule)
            for k in range(3):
                normals[0, j, k] = 0.0
                normals[h - 1, j, k] = 0.0
        num = 0.0
        den = 0.0
        for i in range(1, h - 1):
            r = top + i
            if r < 0 or r >= H:
                continue
            for j in range(1, w - 1):
                s = left + j
                if s < 0 or s >= W:
                    continue
                curv = pixel_curvature(normals, i - 1, i, i + 1, j - 1, j, j + 1, fused)  # curvature_valid
                num += np.float64(curv) * np.float64(dist[v, r, s])
                den += np.float64(curv)
        out[c] = np.float32(num / den) if den > 0.0 else diagonal
    return 0


def compiled_candidate_costs(batch: CandidateBatch, dist_maps: torch.Tensor) -> torch.Tensor | None:
    """Unweighted costs ``(B * V,)`` float32 of a prepared CPU batch (canvas ``c`` = candidate ``c // V`` in view
    ``c % V``), as :meth:`~bop_cender.pose.backend.Backend.candidate_costs` takes them per view; None when a vertex lies
    behind the near plane (the torch pipeline cuts faces there: use it).

    Args:
        batch: :func:`~bop_cender.render.candidate_curvature.prepare_candidates`'s windows and vertices.
        dist_maps: ``(V, H, W)`` float32 distance maps.
    """
    C = int(batch.verts.shape[1])
    if C == 0:
        return torch.zeros(0, dtype=torch.float32)
    inputs = loop_inputs(batch.mesh, batch.R[:, None], batch.t[:, None], batch.K, batch.near, verts=batch.verts)
    if inputs is None:
        return None
    occ = np.zeros((0, 1, 1), dtype=np.float32) if batch.occluder_depth is None else _np(batch.occluder_depth.float())
    out = np.empty(C, dtype=np.float32)
    _canvas_costs(*inputs, _np(batch.lo), _np(batch.extent), np.float32(batch.near), occ,
                  np.float32(OCCLUSION_MARGIN_MM), _np(dist_maps.float()), out)  # fmt: skip
    return torch.from_numpy(out)
