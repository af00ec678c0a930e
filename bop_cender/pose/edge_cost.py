"""A fast proxy of the render-and-compare cost: points on the model's edges looked up in the distance maps.

The paper's cost (:mod:`bop_cender.pose.cost`) renders each candidate, takes the curvature of its
normal map and averages the target's distance map under it. What a rendered curvature image shows of a
rigid part is, to within a pixel, two kinds of mesh edges: **creases** (edges whose two faces meet at
more than the renderer's crease angle, which stay sharp in the shading) on the side facing the camera,
and **contour** edges (one face towards the camera, the other away), wherever they are. Both depend on
the pose only through which faces face the camera, so they can be found without rasterising:

1. once per mesh, :class:`EdgeModel` cuts every edge into segments of at most ``segment_mm`` and keeps
   each edge's two face planes and whether it is a crease;
2. per candidate and view, a face faces the camera when the camera centre (in the model frame) lies
   above its plane; an edge is drawn when it is a contour, or a crease with a face towards the camera;
3. a drawn segment's ends are projected (from its edge's projected ends: homogeneous coordinates are
   linear along the edge, so only the mesh's vertices are projected, not every cut point) and points
   sampled between them; a point behind an already
   placed object (``occluder_depth``: the render cost's rule,
   :data:`~bop_cender.render.candidate_curvature.OCCLUSION_MARGIN_MM`, with the wider
   :data:`EDGE_COINCIDENCE_MM`) or outside the image is left out, as the render cost leaves those
   pixels out;
4. the cost of a view is the length-weighted mean of the bilinearly interpolated distance map at the
   drawn points, the views weighted as in the render cost; a view with no drawn point costs the image
   diagonal.

What it leaves out: self-occlusion (a crease hidden behind another part of the same object still
counts) and the curvature's magnitude (every drawn edge weighs the same). It is a ranking proxy: the
method ranks many candidates and runs the Nelder-Mead refinement on it, then judges the finalists by
the render cost (a render-cost polish was measured and removed: it pulled poses
back onto the pixel grid; ``results/accuracy/README.md``). Being continuous in the pose (bilinear lookups, no pixel
snapping), it also suits Nelder-Mead better than a rendered cost, whose value moves in pixel steps.

Four layouts of the same arithmetic, which agree to float rounding (``tests/pose/test_edge_cost.py``); the backend
chooses (:meth:`~bop_cender.pose.backend.Backend.edge_costs`, ``poses.backend``):

- numba on the CPU (``numba``, ``auto``): one compiled loop over canvases, edges and segments
  (:mod:`bop_cender.pose.edge_kernel`), nothing allocated per segment. A Nelder-Mead step of 3 poses took
  2.6 ms in the compacted torch layout (~430 operators) and takes 0.6 ms here on one 2-core Intel Xeon thread;
- numba on CUDA (``numba``, ``auto`` where numba's CUDA target works): the same loop as one CUDA kernel (a block
  per canvas, :mod:`bop_cender.pose.cuda_edge_kernel`), one launch per call instead of dozens of torch kernels;
- compacted (torch, here: ``torch`` on the CPU): the drawn segments gathered first (``nonzero``: of a part's segments
  only the contour and the creases facing the camera are drawn, often under a tenth, so compaction saves most of
  the work); the CPU's layout before the kernel, kept as its reference;
- dense (torch, here: ``torch`` on CUDA, and ``auto``'s there where the kernel cannot run): every segment of every
  canvas costed with a 0/1 weight. That costs several times the arithmetic but has fixed shapes: no ``nonzero`` or
  data-dependent ``repeat_interleave``, so a call never waits for the device until its result is read, which is what
  bounds the small calls of Nelder-Mead on a GPU (``results/bench/``).

Measured (``scripts/bench_run.py``): see ``results/bench/``.
"""

from __future__ import annotations

import math

import torch

from bop_cender.geometry.check import check_shape
from bop_cender.pose.edge_model import EdgeModel, ranks

#: Points sampled on each drawn segment's projection (segments are at most ``segment_mm`` long).
SAMPLES_PER_SEGMENT = 2

#: An edge point is hidden by a placed object when it lies behind the placed surface or less than this
#: (mm) in front of it (the render cost's rule, with a wider margin: edge points sit on creases and
#: contours, where the surface is steep and the placed object's depth, sampled at pixel centres, can be
#: 1 mm deeper than the point on the same surface).
EDGE_COINCIDENCE_MM = 1.0

#: Canvases (candidate x view) costed together in the compacted layout: bounds the memory of the per-segment arrays.
CANVAS_CHUNK = 512

#: (canvas, segment) pairs costed together in the dense layout: about 250 bytes each at the peak (measured on the
#: CPU), so 2^22 pairs take about 1 GB; a call of 3 poses in 7 views of a 10,000-segment part is 2^18.
DENSE_CHUNK_SEGMENTS = 1 << 22


def torch_edge_view_costs(model: EdgeModel, T: torch.Tensor, V: int, K: torch.Tensor, dist: torch.Tensor,
                          occ: torch.Tensor | None, near: float, dense: bool) -> torch.Tensor:  # fmt: skip
    """Unweighted edge-point costs ``(C,)`` float32 of C canvases (canvas ``c`` in view ``c % V``) in a torch layout:
    ``dense`` (every segment costed with a 0/1 weight, fixed shapes, no wait for the device) or compacted (the drawn
    segments gathered first). Inputs on one device, float32: ``T (C, 4, 4)`` poses in each canvas's camera frame,
    ``K (V, 3, 3)``, ``dist (V, H, W)``, ``occ (V, H, W)`` (:func:`edge_occluder`; None: no occluder); ``near`` (mm):
    points closer to the camera plane are not drawn."""
    C, device = int(T.shape[0]), T.device
    per_view = torch.empty(C, dtype=torch.float32, device=device)
    chunk = max(1, DENSE_CHUNK_SEGMENTS // max(1, model.num_segments)) if dense else CANVAS_CHUNK
    for start in range(0, C, chunk):
        stop = min(C, start + chunk)
        view = torch.arange(start, stop, device=device) % V
        per_view[start:stop] = _canvas_costs(model, T[start:stop], view, K, dist, occ, near, dense)
    return per_view


def _drawn_edges(model: EdgeModel, T: torch.Tensor) -> torch.Tensor:
    """``(C, E)`` bool: the edges drawn in each canvas of pose ``T (C, 4, 4)``: contours (one face towards the
    camera, the other away) and creases with a face towards it."""
    C = T.shape[0]
    R, t = T[:, :3, :3], T[:, :3, 3]
    eye = -torch.einsum("cji,cj->ci", R, t)  # (C, 3) camera centre in the model frame: -R^T t
    planes = model.planes.reshape(-1, 4)  # (2E, 4)
    facing = (torch.addmm(-planes[:, 3], eye, planes[:, :3].T) > 0).view(C, -1, 2)  # (C, E, 2)
    f1, f2 = facing[..., 0], facing[..., 1]
    return (f1 != f2) | (model.crease & (f1 | f2))


def _projected_ends(model: EdgeModel, T: torch.Tensor, view: torch.Tensor, Ks: torch.Tensor) -> torch.Tensor:
    """Homogeneous pixel coordinates ``(C, 3, M)`` (u z, v z, z) of the edges' end vertices in every canvas: one
    matrix product ``(C, 3, 4) x (4, M)`` with ``K [R | t]`` folded in (full float32: where TF32 matmuls are
    enabled on CUDA, t inside the product costs ~0.3 px; nothing enables them)."""
    P = torch.matmul(Ks.index_select(0, view), T[:, :3, :])  # (C, 3, 4)
    return torch.matmul(P, model.projection.ends)


def _canvas_costs(
    model: EdgeModel,
    T: torch.Tensor,
    view: torch.Tensor,
    Ks: torch.Tensor,
    dist: torch.Tensor,
    occ: torch.Tensor | None,
    near: float,
    dense: bool,
) -> torch.Tensor:
    """Unweighted cost ``(C,)`` of C canvases with poses ``T (C, 4, 4)`` in views ``view (C,)``.

    Each drawn segment is sampled at :data:`SAMPLES_PER_SEGMENT` points between its projected ends (a
    segment is short, so its projection is straight to well under a pixel), each weighing a share of
    its length in pixels, as a rendered edge weighs its pixels. The layouts (module docstring) differ only in
    which (canvas, segment) pairs are costed: the drawn ones (compacted), or every one with the undrawn weighted
    0 (``dense``: fixed sizes, nothing read back from the device).
    """
    V, H, W = dist.shape
    C = T.shape[0]
    device = T.device
    proj = model.projection
    drawn = _drawn_edges(model, T)  # (C, E)
    if dense:
        S = proj.seg_edge.shape[0]
        c_idx = torch.arange(C, device=device)[:, None].expand(C, S).reshape(-1)
        s_idx = torch.arange(S, device=device).repeat(C)
    else:
        c_edge, edge = drawn.nonzero(as_tuple=True)
        first, count = model.edge_segments.index_select(0, edge).unbind(1)
        s_idx = torch.repeat_interleave(first, count) + ranks(count)
        c_idx = torch.repeat_interleave(c_edge, count)
    M = proj.ends.shape[1]
    hom = _projected_ends(model, T, view, Ks).reshape(-1)  # (C 3 M): row c 3 + k, column m
    base = c_idx * (3 * M)
    ip = base + proj.seg_from.index_select(0, s_idx)
    iq = base + proj.seg_to.index_select(0, s_idx)
    w = _segment_weights(
        [hom.index_select(0, ip + k * M) for k in range(3)], [hom.index_select(0, iq + k * M) for k in range(3)],
        proj.frac_a.index_select(0, s_idx), proj.frac_b.index_select(0, s_idx), view.index_select(0, c_idx),
        dist, occ, near,
    )  # fmt: skip
    if dense:  # undrawn: 0, even where a non-finite pose made them NaN; a fixed-shape sum (deterministic on CUDA)
        w = torch.where(drawn.index_select(1, proj.seg_edge).reshape(1, -1), w, torch.zeros((), device=device))
        num, den = w.view(2, C, -1).sum(2)
    else:
        num, den = torch.zeros((2, C), device=device).index_add_(1, c_idx, w)
    return torch.where(den > 0, num / den.clamp_min(1e-30), torch.full_like(den, math.hypot(H, W)))


def _segment_weights(
    p: list[torch.Tensor],
    q: list[torch.Tensor],
    frac_a: torch.Tensor,
    frac_b: torch.Tensor,
    view: torch.Tensor,
    dist: torch.Tensor,
    occ: torch.Tensor | None,
    near: float,
) -> torch.Tensor:
    """``(2, n)``: per segment, the summed length-weighted distance of its sample points and their summed weight.

    Args:
        p, q: three ``(n,)`` homogeneous pixel coordinates (u z, v z, z) each of the start and end of each
            segment's edge.
        frac_a, frac_b: ``(n,)`` where the segment starts and ends along its edge.
        view: ``(n,)`` view of each segment.
        dist, occ, near: as :func:`_canvas_costs`.
    """
    V, H, W = dist.shape
    za, zb = torch.lerp(p[2], q[2], frac_a), torch.lerp(p[2], q[2], frac_b)
    inv_a, inv_b = za.clamp_min(near).reciprocal(), zb.clamp_min(near).reciprocal()
    xa, ya = torch.lerp(p[0], q[0], frac_a) * inv_a, torch.lerp(p[1], q[1], frac_a) * inv_a
    xb, yb = torch.lerp(p[0], q[0], frac_b) * inv_b, torch.lerp(p[1], q[1], frac_b) * inv_b
    frac = (torch.arange(SAMPLES_PER_SEGMENT, device=xa.device, dtype=xa.dtype) + 0.5) / SAMPLES_PER_SEGMENT
    # a non-finite pose (only the dense layout costs undrawn segments of one) gives NaN points: moved out of the
    # image (not kept) before they index a map
    xs = torch.lerp(xa[:, None], xb[:, None], frac).nan_to_num_(nan=-1.0)  # (n, k)
    ys = torch.lerp(ya[:, None], yb[:, None], frac).nan_to_num_(nan=-1.0)
    length = torch.hypot(xb - xa, yb - ya)[:, None] / SAMPLES_PER_SEGMENT
    keep = (torch.minimum(za, zb) >= near)[:, None] & (xs >= 0) & (xs < W) & (ys >= 0) & (ys < H)
    v_of = view[:, None].expand_as(xs)
    if occ is not None:
        zs = torch.lerp(za[:, None], zb[:, None], frac)
        u_i = xs.floor().clamp(0, W - 1).long()
        v_i = ys.floor().clamp(0, H - 1).long()
        o = occ.reshape(-1).index_select(0, ((v_of * H + v_i) * W + u_i).reshape(-1)).view_as(xs)
        keep &= ~((o > 0) & (zs > o - EDGE_COINCIDENCE_MM))
    d = _bilinear(dist, v_of.reshape(-1), (xs - 0.5).reshape(-1), (ys - 0.5).reshape(-1)).view_as(xs)
    zero = torch.zeros((), device=xs.device)
    return torch.stack([torch.where(keep, length * d, zero).sum(1), torch.where(keep, length, zero).sum(1)])


def edge_occluder(occluder_depth: torch.Tensor) -> torch.Tensor:
    """The occluder depth ``(V, H, W)`` that :meth:`~bop_cender.pose.backend.Backend.edge_costs` wants: each pixel the nearest placed surface
    in its 3 x 3 neighbourhood (0 where none).

    Why: a candidate that duplicates a placed object has its contour exactly on the placed object's
    contour, where a point falls on either side of the occluder's last pixel; unhidden, those points
    fit perfectly and make the duplicate the best candidate. Widened by a pixel, the occluder hides them,
    as the render cost hides the duplicate's pixels.
    """
    check_shape(occluder_depth, "V H W", "occluder_depth")
    far = torch.where(occluder_depth > 0, occluder_depth, torch.full_like(occluder_depth, float("inf")))
    near = -torch.nn.functional.max_pool2d(-far[:, None], 3, stride=1, padding=1)[:, 0]
    return torch.where(torch.isfinite(near), near, torch.zeros_like(near))


def _bilinear(maps: torch.Tensor, view: torch.Tensor, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """``maps (V, H, W)`` at continuous ``(x, y)`` (pixel-centre coordinates, clamped to the image) of view ``view``."""
    V, H, W = maps.shape
    x = x.clamp(0, W - 1)
    y = y.clamp(0, H - 1)
    x0 = x.floor().clamp(max=W - 2 if W > 1 else 0)
    y0 = y.floor().clamp(max=H - 2 if H > 1 else 0)
    fx, fy = x - x0, y - y0
    base = (view * H + y0.long()) * W + x0.long()
    flat = maps.reshape(-1)
    dx = 1 if W > 1 else 0
    dy = W if H > 1 else 0
    top = torch.lerp(flat.index_select(0, base), flat.index_select(0, base + dx), fx)
    bottom = torch.lerp(flat.index_select(0, base + dy), flat.index_select(0, base + dy + dx), fx)
    return torch.lerp(top, bottom, fy)
