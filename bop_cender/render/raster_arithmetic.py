"""The rasteriser's per-face and per-pixel arithmetic, written once and compiled for the CPU and for CUDA.

Why one source. The compiled CPU loops (:mod:`bop_cender.render.compiled_raster`) and the CUDA kernels
(:mod:`bop_cender.render.cuda_loops` and the kernels built on it) must give the torch renderer's bits (the CPU) or the
same arithmetic to float32 rounding (a GPU). So the steps are written here once, as a factory:
:func:`raster_arithmetic` takes the target's compiler (``jit``: numba's CPU ``njit``, numba's CUDA device ``jit``, or
nothing in numba's CUDA simulator) and the two steps that differ by target, the z-buffer write (``keep_fragment``: a
plain compare here, an atomic maximum on CUDA) and the float32 square root (``sqrt32``), and returns the compiled
functions as a :class:`RasterArithmetic`. Each function calls the others as names of the factory's scope, so every
name is visible to a reader, ruff and an IDE, and each target's copy calls its own target's functions.

They allocate nothing and write only through their array arguments. On the CPU they are inlined
(``inline="always"``): as separate calls, with the curvature read from flat normals, the CPU cost loop ran 20 %
slower (264-278 against 333-349 calls/s before the split).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

_COORD_LIMIT = np.float32(1e7)  # as scanline._COORD_LIMIT
_HALF = np.float32(0.5)

#: Floats in a face's shading row (``face_row``): the planes of the three normal components, then of 1/z.
TABLE_WIDTH = 12


class RasterArithmetic(NamedTuple):
    """The rasteriser's steps compiled for one target (:func:`raster_arithmetic`); each function's docstring says what
    it computes."""

    torch_fma: Callable
    key_levels: Callable
    key_scale: Callable
    face_row: Callable
    key_plane: Callable
    scan_face: Callable
    shade: Callable
    pixel_curvature: Callable
    keep_fragment: Callable
    sqrt32: Callable


def raster_arithmetic(jit: Callable, keep_fragment: Callable, sqrt32: Callable) -> RasterArithmetic:
    """The rasteriser's steps compiled by ``jit`` (a decorator; the identity gives the plain Python functions), calling
    ``keep_fragment(best_key, best_w, p, q, key, f, quantised)`` for each fragment and ``sqrt32(x)`` for float32 roots
    (both already compiled for the target)."""

    @jit
    def torch_fma(a, b, c, fused):
        """``a * b + c`` as torch's CPU ``addcmul`` computes it: with ``fused``, rounded once to float32 (a fused
        multiply-add, as its AVX2 and AVX-512 kernels do; the float32 product is exact in float64), else the product
        rounded, then the sum."""
        if fused:
            return np.float32(np.float64(a) * np.float64(b) + np.float64(c))
        return np.float32(a * b) + c

    @jit
    def _cross(a0, a1, a2, b0, b1, b2):
        return (a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0)

    @jit
    def _rotate(R, a, n, fused):
        """Axis ``a`` of the model-frame normal ``n (3,)`` rotated by ``R (3, 3)`` (the torch order of operations)."""
        return torch_fma(R[a, 2], n[2], torch_fma(R[a, 1], n[1], R[a, 0] * n[0], fused), fused)

    @jit
    def _plane(cv, s00, s01, s02, s11, s12, inv_det, fused):
        """``c K^-1 / det`` for the upper-triangular ``K^-1`` (raster._face_table's ``plane``)."""
        return (
            cv[0] * s00,
            torch_fma(cv[1], s11, cv[0] * s01, fused),
            torch_fma(cv[2], inv_det, torch_fma(cv[1], s12, cv[0] * s02, fused), fused),
        )

    @jit
    def _edge(xa, ya, ia, xb, yb, ib):
        """Edge a-b as (anchor x, anchor y, dx/dy), anchored at the end point of lower vertex id."""
        if ib < ia:
            xa, ya, xb, yb = xb, yb, xa, ya
        return (xa, ya, (xb - xa) / (yb - ya))

    @jit
    def key_levels(depth_bits, quantised):
        """The largest quantised depth level of int32 keys (0 for exact keys)."""
        return np.float32((1 << depth_bits) - 1 if quantised else 0)

    @jit
    def key_scale(z_lo, z_hi, near, levels):
        """``(w_lo, scale)``: the quantisation range of a canvas's int32 keys (KeyCodec.depth_planes) from its vertices'
        depth range ``z_lo .. z_hi``: level = (1/z - w_lo) * scale."""
        w_lo = np.float32(1.0) / max(z_hi, near)
        w_hi = np.float32(1.0) / max(z_lo, near)
        span = w_hi - w_lo
        # torch's `levels / span` on a tensor is `span.reciprocal() * levels`: two roundings
        scale = (np.float32(1.0) / max(span, np.float32(1e-30))) * levels if span > 0 else np.float32(0.0)
        return w_lo, scale

    @jit
    def face_row(cam, faces, face_instance, corner_normals, R, K_inv, f, fused, row):
        """Face ``f``'s shading row (raster._face_table) into ``row[:12]``: for each normal component the plane (x, y, 1)
        of its perspective-correct value, then the plane of 1/z, all at image coordinates. Scalars only: no allocation
        per face."""
        inst = face_instance[f]
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        a0, a1, a2 = cam[i0, 0], cam[i0, 1], cam[i0, 2]
        b0, b1, b2 = cam[i1, 0], cam[i1, 1], cam[i1, 2]
        d0, d1, d2 = cam[i2, 0], cam[i2, 1], cam[i2, 2]
        e10, e11, e12 = b0 - a0, b1 - a1, b2 - a2
        e20, e21, e22 = d0 - a0, d1 - a1, d2 - a2
        nrm = _cross(e10, e11, e12, e20, e21, e22)
        inv_det = np.float32(1.0) / torch_fma(a2, nrm[2], torch_fma(a1, nrm[1], a0 * nrm[0], fused), fused)
        s00 = K_inv[0] * inv_det
        s01 = K_inv[1] * inv_det
        s02 = K_inv[2] * inv_det
        s11 = K_inv[4] * inv_det
        s12 = K_inv[5] * inv_det
        p0 = _plane(_cross(b0, b1, b2, d0 - b0, d1 - b1, d2 - b2), s00, s01, s02, s11, s12, inv_det, fused)
        p1 = _plane(_cross(e20, e21, e22, d0, d1, d2), s00, s01, s02, s11, s12, inv_det, fused)
        p2 = _plane(_cross(a0, a1, a2, e10, e11, e12), s00, s01, s02, s11, s12, inv_det, fused)
        for a in range(3):
            n0 = _rotate(R[inst], a, corner_normals[f, 0], fused)
            n1 = _rotate(R[inst], a, corner_normals[f, 1], fused)
            n2 = _rotate(R[inst], a, corner_normals[f, 2], fused)
            for k in range(3):
                row[3 * a + k] = torch_fma(n2, p2[k], torch_fma(n1, p1[k], n0 * p0[k], fused), fused)
        pz = _plane(nrm, s00, s01, s02, s11, s12, inv_det, fused)
        row[9] = pz[0]
        row[10] = pz[1]
        row[11] = pz[2]

    @jit
    def key_plane(row, quantised, scale, w_lo):
        """The plane ``(qa, qb, qc)`` of the key's depth quantity (KeyCodec.depth_planes) of a shading row, the
        pixel-centre half folded in: the quantity at pixel (column u, row v) is ``qa * u + qb * v + qc``."""
        if quantised:
            qa = row[9] * scale
            qb = row[10] * scale
            qc = (row[11] - w_lo) * scale
        else:
            qa, qb, qc = row[9], row[10], row[11]
        qc = qc + _HALF * (qa + qb)
        return qa, qb, qc

    @jit
    def scan_face(px, py, i0, i1, i2, f, qa, qb, qc, v0, u0, h, w, quantised, levels, face_bits, fused, best_key,
                  best_w):  # fmt: skip
        """Scan face ``f`` (corners ``i0, i1, i2``) into the window's z-buffer ``best_key, best_w`` (flat, pixel
        ``i * w + j``) through :func:`keep_fragment` (scanline.scan): corners sorted by y, ties in order (the same three
        compare-swaps), the top-left rule at pixel centres."""
        y0, x0, id0 = py[i0], px[i0], i0
        y1, x1, id1 = py[i1], px[i1], i1
        y2, x2, id2 = py[i2], px[i2], i2
        if y1 < y0:
            y0, x0, id0, y1, x1, id1 = y1, x1, id1, y0, x0, id0
        if y2 < y1:
            y1, x1, id1, y2, x2, id2 = y2, x2, id2, y1, x1, id1
        if y1 < y0:
            y0, x0, id0, y1, x1, id1 = y1, x1, id1, y0, x0, id0
        cross = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if cross == 0:
            return
        long_left = cross > 0
        long_edge = _edge(x0, y0, id0, x2, y2, id2)
        for half in range(2):
            if half == 0:
                short = _edge(x0, y0, id0, x1, y1, id1)
                y_top, y_bot = y0, y1
            else:
                short = _edge(x1, y1, id1, x2, y2, id2)
                y_top, y_bot = y1, y2
            left = long_edge if long_left else short
            right = short if long_left else long_edge
            y_top = min(max(y_top, -_COORD_LIMIT), _COORD_LIMIT)
            y_bot = min(max(y_bot, -_COORD_LIMIT), _COORD_LIMIT)
            row_start = max(math.ceil(y_top - _HALF), v0)
            row_end = min(math.ceil(y_bot - _HALF), v0 + h)
            la_y, la_s, la_x = left[1] - _HALF, left[2], left[0] - _HALF
            ra_y, ra_s, ra_x = right[1] - _HALF, right[2], right[0] - _HALF
            for r in range(row_start, row_end):
                y = np.float32(r)
                x_left = (y - la_y) * la_s + la_x
                x_right = (y - ra_y) * ra_s + ra_x
                if not (x_left == x_left and x_right == x_right):  # NaN bounds: no pixel (as in torch)
                    continue
                col_start = max(np.float32(math.ceil(min(max(x_left, -_COORD_LIMIT), _COORD_LIMIT))), np.float32(u0))
                col_end = min(np.float32(math.ceil(min(max(x_right, -_COORD_LIMIT), _COORD_LIMIT))), np.float32(u0 + w))
                n_cols = int(col_end - col_start)
                if n_cols <= 0:
                    continue
                q_start = torch_fma(qb, y, col_start * qa, fused) + qc
                p0 = (r - v0) * w + int(col_start) - u0
                for k in range(n_cols):
                    q = torch_fma(qa, np.float32(k), q_start, fused)
                    key = (
                        (np.int64(min(max(q, np.float32(0.0)), levels)) << face_bits) | f if quantised else np.int64(f)
                    )
                    keep_fragment(best_key, best_w, p0 + k, q, key, f, quantised)

    @jit
    def shade(row, x, y, fused):
        """``(depth, n0, n1, n2)``: z and the unit normal of a shading row at image point (x, y) (resolve.shade)."""
        depth = np.float32(1.0) / torch_fma(row[10], y, torch_fma(row[9], x, row[11], fused), fused)
        n0 = torch_fma(row[1], y, torch_fma(row[0], x, row[2], fused), fused)
        n1 = torch_fma(row[4], y, torch_fma(row[3], x, row[5], fused), fused)
        n2 = torch_fma(row[7], y, torch_fma(row[6], x, row[8], fused), fused)
        inv = np.float32(1.0) / sqrt32(
            max(torch_fma(n2, n2, torch_fma(n1, n1, n0 * n0, fused), fused), np.float32(1e-30))
        )
        return depth, n0 * inv, n1 * inv, n2 * inv

    @jit
    def pixel_curvature(normals, i0, i, i2, j0, j, j2, fused):
        """The curvature at pixel ``(i, j)`` of normal maps ``(h, w, 3)`` from rows ``i0, i, i2`` and columns
        ``j0, j, j2`` (the caller's border rule), as :func:`~bop_cender.render.curvature.curvature_valid` computes it:
        the Prewitt sums in its order, ``gx0 * gx0``, then torch's multiply-adds (``fused``: :data:`ADDCMUL_FUSED`), the
        square root. Float32, so a threshold on it sees torch's value (3.0, a clean step from a unit normal to
        background, sits exactly on stage 3's edge threshold)."""
        total = np.float32(0.0)
        for k in range(3):
            gx = (normals[i0, j2, k] + normals[i, j2, k] + normals[i2, j2, k]) - (
                normals[i0, j0, k] + normals[i, j0, k] + normals[i2, j0, k]
            )
            gy = (normals[i2, j0, k] + normals[i2, j, k] + normals[i2, j2, k]) - (
                normals[i0, j0, k] + normals[i0, j, k] + normals[i0, j2, k]
            )
            total = gx * gx if k == 0 else torch_fma(gx, gx, total, fused)
            total = torch_fma(gy, gy, total, fused)
        return sqrt32(total)

    return RasterArithmetic(torch_fma, key_levels, key_scale, face_row, key_plane, scan_face, shade, pixel_curvature,
                            keep_fragment, sqrt32)  # fmt: skip
