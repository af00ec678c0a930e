"""The edge proxy's CPU layout: one compiled loop per canvas instead of ~430 torch operators per call.

Why. On the CPU, :meth:`~bop_cender.pose.backend.Backend.edge_costs` in its compacted torch layout spends a
Nelder-Mead step of 3 poses (21 canvases, a few thousand drawn segments) in ~430 small operators: the
arithmetic of a segment is a few dozen flops, but each operator reads and writes whole arrays and costs
its dispatch. Stage 3 makes thousands of such calls per scene (the edge search's Nelder-Mead is half of
its time, ``results/bench/``). Here the same arithmetic runs as one loop (numba, compiled once and cached on
disk): per canvas, each edge's facing test, then the drawn edges' segments sampled, looked up and summed in
registers, with nothing allocated per segment. With more than one torch thread the canvases are spread over
them, each canvas summed by one thread in a fixed order: the same bits for any thread count
(:mod:`bop_cender.render.numba_loops`: why one thread runs a serial compilation).

The arithmetic is that of the torch layouts (``edge_cost._canvas_costs`` and ``_segment_weights``, module
docstring of :mod:`bop_cender.pose.edge_cost`), in float64 instead of float32: the costs agree to float32
rounding (``tests/pose/test_edge_cost.py``), except where a face lies within rounding of edge-on, whose
edge one layout draws and the other not.

numba is imported on the first kernel call (the numba backend imports this module then, :mod:`bop_cender.pose.backend`:
half a second), so that nothing else pays for it. Its serial compilation (4 s) is cached on disk.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numba
import numpy as np
import torch

from bop_cender.pose.edge_model import EdgeModel
from bop_cender.render.numba_cache import cached_njit
from bop_cender.render.numba_loops import as_numpy, canvas_loop


class EdgeArithmetic(NamedTuple):
    """The edge proxy's per-canvas steps compiled for one target (:func:`edge_arithmetic`)."""

    canvas_projection: Callable
    edge_sums: Callable


def edge_arithmetic(jit: Callable) -> EdgeArithmetic:
    """The edge proxy's per-canvas steps compiled by ``jit``: numba's CPU ``njit`` (inlined in :func:`canvas_costs`),
    numba's CUDA ``jit(device=True)`` (:mod:`bop_cender.pose.cuda_edge_kernel`), or the identity (the plain functions,
    numba's CUDA simulator): one source for the arithmetic of both targets."""

    @jit
    def canvas_projection(T, Ks, c, v, P):
        """Fill ``P (3, 4)`` with ``K_v [R | t]`` of canvas ``c`` (float64) and return the camera centre in the model
        frame, ``-R^T t``."""
        for i in range(3):
            for j in range(4):
                acc = 0.0
                for k in range(3):
                    acc += np.float64(Ks[v, i, k]) * np.float64(T[c, k, j])
                P[i, j] = acc
        ex = -(T[c, 0, 0] * T[c, 0, 3] + T[c, 1, 0] * T[c, 1, 3] + T[c, 2, 0] * T[c, 2, 3])
        ey = -(T[c, 0, 1] * T[c, 0, 3] + T[c, 1, 1] * T[c, 1, 3] + T[c, 2, 1] * T[c, 2, 3])
        ez = -(T[c, 0, 2] * T[c, 0, 3] + T[c, 1, 2] * T[c, 1, 3] + T[c, 2, 2] * T[c, 2, 3])
        return ex, ey, ez

    @jit
    def edge_sums(P, ex, ey, ez, e_first, e_step, v, dist, occ, planes, crease, edge_first, edge_count, seg_from, seg_to,
                  frac_a, frac_b, ends, near, samples, coincidence):  # fmt: skip
        """``(num, den)`` of edges ``e_first, e_first + e_step, ...`` in canvas view ``v`` seen through ``P`` from the
        model frame's ``(ex, ey, ez)``: the length-weighted distance-map samples of their drawn segments and the lengths
        (an edge is drawn where it is a silhouette or a crease facing the camera). The CPU loop takes every edge of a
        canvas (``0, 1``), a CUDA thread its share (``tid, threads``)."""
        H, W = dist.shape[1], dist.shape[2]
        has_occ = occ.shape[0] > 0
        num = 0.0
        den = 0.0
        for e in range(e_first, planes.shape[0], e_step):
            f1 = planes[e, 0, 0] * ex + planes[e, 0, 1] * ey + planes[e, 0, 2] * ez - planes[e, 0, 3] > 0.0
            f2 = planes[e, 1, 0] * ex + planes[e, 1, 1] * ey + planes[e, 1, 2] * ez - planes[e, 1, 3] > 0.0
            if not ((f1 != f2) or (crease[e] and (f1 or f2))):
                continue
            first = edge_first[e]
            a = seg_from[first]
            b = seg_to[first]
            pu = P[0, 0] * ends[0, a] + P[0, 1] * ends[1, a] + P[0, 2] * ends[2, a] + P[0, 3]
            pv = P[1, 0] * ends[0, a] + P[1, 1] * ends[1, a] + P[1, 2] * ends[2, a] + P[1, 3]
            pz = P[2, 0] * ends[0, a] + P[2, 1] * ends[1, a] + P[2, 2] * ends[2, a] + P[2, 3]
            qu = P[0, 0] * ends[0, b] + P[0, 1] * ends[1, b] + P[0, 2] * ends[2, b] + P[0, 3]
            qv = P[1, 0] * ends[0, b] + P[1, 1] * ends[1, b] + P[1, 2] * ends[2, b] + P[1, 3]
            qz = P[2, 0] * ends[0, b] + P[2, 1] * ends[1, b] + P[2, 2] * ends[2, b] + P[2, 3]
            for s in range(first, first + edge_count[e]):
                fa = np.float64(frac_a[s])
                fb = np.float64(frac_b[s])
                za = pz + fa * (qz - pz)
                zb = pz + fb * (qz - pz)
                if min(za, zb) < near:
                    continue
                xa = (pu + fa * (qu - pu)) / za
                ya = (pv + fa * (qv - pv)) / za
                xb = (pu + fb * (qu - pu)) / zb
                yb = (pv + fb * (qv - pv)) / zb
                length = math.hypot(xb - xa, yb - ya) / samples
                for k in range(samples):
                    f = (k + 0.5) / samples
                    x = xa + f * (xb - xa)
                    y = ya + f * (yb - ya)
                    if not (x >= 0.0 and x < W and y >= 0.0 and y < H):
                        continue
                    if has_occ:
                        o = occ[v, min(max(int(math.floor(y)), 0), H - 1), min(max(int(math.floor(x)), 0), W - 1)]
                        if o > 0.0 and za + f * (zb - za) > o - coincidence:
                            continue
                    # bilinear, pixel-centre coordinates clamped to the image (edge_cost._bilinear)
                    gx = min(max(x - 0.5, 0.0), W - 1.0)
                    gy = min(max(y - 0.5, 0.0), H - 1.0)
                    x0 = min(math.floor(gx), max(W - 2, 0))
                    y0 = min(math.floor(gy), max(H - 2, 0))
                    tx = gx - x0
                    ty = gy - y0
                    i0 = int(x0)
                    j0 = int(y0)
                    i1 = i0 + (1 if W > 1 else 0)
                    j1 = j0 + (1 if H > 1 else 0)
                    top = dist[v, j0, i0] + tx * (dist[v, j0, i1] - dist[v, j0, i0])
                    bottom = dist[v, j1, i0] + tx * (dist[v, j1, i1] - dist[v, j1, i0])
                    num += length * (top + ty * (bottom - top))
                    den += length
        return num, den

    return EdgeArithmetic(canvas_projection, edge_sums)


#: The steps compiled for the CPU, inlined where they are called.
CPU_ARITHMETIC = edge_arithmetic(cached_njit(nogil=True, inline="always"))
canvas_projection = CPU_ARITHMETIC.canvas_projection
edge_sums = CPU_ARITHMETIC.edge_sums


@canvas_loop
def canvas_costs(
    T, view, Ks, dist, occ, planes, crease, edge_first, edge_count, seg_from, seg_to, frac_a, frac_b, ends,
    near, samples, coincidence, out,
):  # fmt: skip
    """``out (C,)`` = the cost of each canvas (float64 out; inputs as :func:`kernel_canvas_costs` passes them:
    ``occ`` with no rows for none)."""
    C = T.shape[0]
    diagonal = math.hypot(dist.shape[1], dist.shape[2])
    for c in numba.prange(C):
        v = view[c]
        P = np.empty((3, 4))
        ex, ey, ez = canvas_projection(T, Ks, c, v, P)
        num, den = edge_sums(P, ex, ey, ez, 0, 1, v, dist, occ, planes, crease, edge_first, edge_count, seg_from,
                             seg_to, frac_a, frac_b, ends, near, samples, coincidence)  # fmt: skip
        out[c] = num / den if den > 0.0 else diagonal


def kernel_canvas_costs(
    model: EdgeModel,
    T: torch.Tensor,
    view: torch.Tensor,
    Ks: torch.Tensor,
    dist: torch.Tensor,
    occ: torch.Tensor | None,
    near: float,
    samples: int,
    coincidence_mm: float,
) -> torch.Tensor:
    """Unweighted cost ``(C,)`` float32 of C canvases (poses ``T (C, 4, 4)`` in views ``view (C,)``), as the torch
    layouts' ``_canvas_costs`` (arguments alike; CPU tensors only)."""
    proj = model.projection
    first, count = model.edge_segments.unbind(1)
    out = np.empty(T.shape[0], dtype=np.float64)
    inputs = [as_numpy(x) for x in (T, view, Ks, dist)]
    inputs.append(as_numpy(occ) if occ is not None else np.zeros((0, 1, 1), np.float32))  # no rows: no occluder
    tables = (model.planes, model.crease, first, count, proj.seg_from, proj.seg_to, proj.frac_a, proj.frac_b, proj.ends)
    canvas_costs(*inputs, *(as_numpy(x) for x in tables), float(near), int(samples), float(coincidence_mm), out)
    return torch.from_numpy(out).to(torch.float32)
