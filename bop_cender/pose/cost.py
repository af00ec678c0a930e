"""The render-and-compare cost (paper, "Cost function"): rendered curvature against distance maps.

Per view, ``cost_v = sum(curv * dist) / sum(curv)``: the curvature-weighted mean distance (pixels) from
a rendered curvature pixel to the nearest true pixel of the target's binary curvature image. The total
is ``sum_v w_v cost_v`` with per-view weights. A view in which the candidate has no curvature at all
(nothing of it inside that view's image) costs the image diagonal, the largest distance a distance map
can hold, so such candidates rank last instead of producing NaN.

Windows: curvature is rendered only in a window per (candidate, view) (see :mod:`bop_cender.render`).
Window pixels beyond the image border do not count (no target there): their curvature is left out of
both sums.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
import torch

from bop_cender.render.candidate_curvature import CandidateBatch, CurvatureAtlas, chunk_curvature

ArrayLike = np.ndarray | torch.Tensor


def distance_map(binary_edges: ArrayLike) -> ArrayLike:
    """Distance ``(H, W)`` float32 from each pixel to the nearest true pixel of ``binary_edges (H, W)``.

    Exact Euclidean distance (``cv2.distanceTransform`` with ``DIST_L2, DIST_MASK_PRECISE``; docs/performance.md:
    0.5 ms per 320x256 map, 3x faster than scipy's EDT), 0 on the true pixels, the same bits on every
    call. With no true pixel at all, every pixel gets the image diagonal. Returns the input's type
    (NumPy, or torch on the input's device).
    """
    is_torch = isinstance(binary_edges, torch.Tensor)
    edges = binary_edges.detach().cpu().numpy() if is_torch else np.asarray(binary_edges)
    if edges.ndim != 2:
        raise ValueError(f"expected a 2-D edge image, got shape {edges.shape}")
    if edges.any():
        # OpenCV's result differs in the last bit with the output buffer's alignment (its SIMD paths):
        # a 64-byte aligned buffer makes it the same on every call.
        inverted = (~edges.astype(bool)).astype(np.uint8)
        dist = cv2.distanceTransform(inverted, cv2.DIST_L2, cv2.DIST_MASK_PRECISE, dst=_aligned_float32(edges.shape))
    else:
        dist = np.full(edges.shape, math.hypot(*edges.shape), dtype=np.float32)
    dist = dist.astype(np.float32, copy=False)
    return torch.from_numpy(dist).to(binary_edges.device) if is_torch else dist


def _aligned_float32(shape: tuple[int, ...], alignment: int = 64) -> np.ndarray:
    """An uninitialised float32 array whose data starts on an ``alignment``-byte boundary."""
    size = int(np.prod(shape)) * 4
    raw = np.empty(size + alignment, dtype=np.uint8)
    start = -raw.ctypes.data % alignment
    return raw[start : start + size].view(np.float32).reshape(shape)


def distance_maps(binary_edges: ArrayLike) -> ArrayLike:
    """:func:`distance_map` of each view: ``(V, H, W)`` -> ``(V, H, W)`` float32, same type as the input."""
    if isinstance(binary_edges, torch.Tensor):
        return torch.stack([distance_map(e) for e in binary_edges]) if len(binary_edges) else binary_edges.float()
    return np.stack([distance_map(e) for e in np.asarray(binary_edges)])


def render_cost(
    curv_window: torch.Tensor, dist_maps: torch.Tensor, offsets: torch.Tensor, view_weights: torch.Tensor
) -> torch.Tensor:
    """Cost ``(B,)`` of B candidates from their curvature windows.

    Args:
        curv_window: ``(B, V, S, S)`` rendered curvature in each (candidate, view) window (any window
            height and width).
        dist_maps: ``(V, H, W)`` distance maps of the target curvature (pixels).
        offsets: ``(B, V, 2)`` int64 window origin (row, column) in the image.
        view_weights: ``(V,)`` weights ``w_v``.

    Returns:
        ``sum_v w_v * sum(curv * dist) / sum(curv)`` per candidate, sums over window pixels inside the
        image; a view with no curvature there costs the image diagonal.
    """
    B, V, h, w = curv_window.shape
    per_view = view_costs(curv_window.reshape(B * V, h, w), dist_maps, offsets.reshape(B * V, 2))
    return (per_view.view(B, V) * view_weights.to(per_view)).sum(1)


def view_costs(curv: torch.Tensor, dist_maps: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
    """Unweighted cost ``(C,)`` of C canvases (canvas c is view ``c % V``) from curvature windows ``(C, h, w)``.

    Args:
        curv: curvature windows.
        dist_maps: ``(V, H, W)`` distance maps.
        offsets: ``(C, 2)`` int64 window origins (row, column).
    """
    C, h, w = curv.shape
    V, H, W = dist_maps.shape
    device = curv.device
    rows = offsets[:, 0, None] + torch.arange(h, device=device)  # (C, h)
    cols = offsets[:, 1, None] + torch.arange(w, device=device)  # (C, w)
    view = torch.arange(C, device=device) % V
    index = ((view[:, None] * H + rows.clamp(0, H - 1)) * W)[:, :, None] + cols.clamp(0, W - 1)[:, None, :]
    dist = dist_maps.reshape(-1).index_select(0, index.reshape(-1)).view(C, h * w)
    flat = curv.reshape(C, h * w)
    if bool((offsets.amin() < 0) | (offsets[:, 0].amax() + h > H) | (offsets[:, 1].amax() + w > W)):
        inside = ((rows >= 0) & (rows < H)).to(curv.dtype)[:, :, None] * ((cols >= 0) & (cols < W)).to(curv.dtype)[
            :, None, :
        ]
        flat = flat * inside.view(C, h * w)
    num = torch.bmm(flat[:, None, :], dist[:, :, None]).view(C)
    den = flat.sum(1)
    diagonal = math.hypot(H, W)
    return torch.where(den > 0, num / den.clamp_min(1e-30), torch.full_like(den, diagonal))


def atlas_view_costs(batch: CandidateBatch, dist_maps: torch.Tensor, workers: int = 1) -> torch.Tensor:
    """Unweighted costs ``(B * V,)`` float32 of a prepared batch (canvas ``c`` = candidate ``c // V`` in view
    ``c % V``) by the torch atlases: the candidates rendered in tight windows, chunk by chunk
    (:mod:`bop_cender.render.candidate_curvature`), equal to float rounding to :func:`render_cost` of
    :func:`~bop_cender.render.rasterizer.render_candidates` windows. What the ``torch`` backend's candidate costs are
    (:meth:`~bop_cender.pose.backend.Backend.candidate_costs`), and the others' where their loop or kernel declines.

    Args:
        batch: :func:`~bop_cender.render.candidate_curvature.prepare_candidates`'s windows and vertices.
        dist_maps: ``(V, H, W)`` float32 distance maps on the batch's device.
        workers: threads that render chunks side by side (CPU; on CUDA the chunks queue on one stream anyway).
            Chunks are independent, so the result is the same bits; worth it only with ``torch.set_num_threads(1)``
            and free cores (on a shared machine, one intra-op thread per process is the safe default: OpenMP threads
            that wait for a busy core make every parallel op cost a scheduler time slice).
    """
    device = dist_maps.device
    per_view = torch.zeros(int(batch.verts.shape[1]), dtype=torch.float32, device=device)

    def run(chunk: tuple[int, int, int]) -> tuple[torch.Tensor, torch.Tensor]:
        atlas = chunk_curvature(batch, chunk)
        return atlas.canvases, _atlas_costs(atlas, dist_maps)

    if workers > 1 and len(batch.chunks) > 1 and device.type == "cpu":  # one stream on CUDA: threads gain nothing
        with ThreadPoolExecutor(workers) as pool:
            results = list(pool.map(run, batch.chunks))
    else:
        results = [run(chunk) for chunk in batch.chunks]
    for canvases, costs in results:
        per_view.index_copy_(0, canvases, costs)
    return per_view


def _atlas_costs(atlas: CurvatureAtlas, dist_maps: torch.Tensor) -> torch.Tensor:
    """Unweighted cost ``(c,)`` of the canvases of a curvature atlas (canvas index ``b * V + v``)."""
    V, H, W = dist_maps.shape
    device = dist_maps.device
    rows, cols = atlas.curvature.shape
    rc = atlas.row_canvas
    view = (atlas.canvases % V).to(torch.int32)
    v = atlas.row_image.to(torch.int32)
    u = (atlas.col_image.to(torch.int32).index_select(0, rc))[:, None] + torch.arange(
        cols, dtype=torch.int32, device=device
    )
    index = ((view.index_select(0, rc) * H + v.clamp(0, H - 1)) * W)[:, None] + u.clamp(0, W - 1)
    dist = dist_maps.reshape(-1).index_select(0, index.view(-1)).view(rows, cols)
    curv = atlas.curvature
    if bool((v.amin() < 0) | (v.amax() >= H) | (u.amin() < 0) | (u.amax() >= W)):
        curv = curv * (((v >= 0) & (v < H))[:, None] & (u >= 0) & (u < W))
    n = atlas.canvases.numel()
    num = torch.zeros(n, dtype=curv.dtype, device=device).index_add_(0, rc, (curv * dist).sum(1))
    den = torch.zeros(n, dtype=curv.dtype, device=device).index_add_(0, rc, curv.sum(1))
    return torch.where(den > 0, num / den.clamp_min(1e-30), torch.full_like(den, math.hypot(H, W)))
