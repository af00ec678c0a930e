"""Curvature of pose candidates in tight windows: the inner loop of the render-and-compare cost.

Unlike :func:`~bop_cender.render.rasterizer.render_candidates` (square windows from the bounding
sphere: a public, predictable layout), this gives every (candidate, view) canvas the smallest window
that holds the projected bounding box of the mesh's vertices plus the curvature ring, and packs the
windows of a chunk of canvases into one *atlas*: windows of one width (the chunk's widest) and their
own heights, stacked one below the other. Canvases are taken in order of window width, so that little
width is wasted. The dense work (z-buffer, normal maps, Prewitt) then follows the object's pixels, and
a chunk's arrays stay small enough to live in the CPU's caches.

Why stacking is exact: each window keeps 2 background rows and columns around the pixels the object
can cover (its vertices' box), the first and last row of every window are forced to background, and
the Prewitt stencil reaches one pixel, so no curvature leaks from one window into the pixels of another
that count. Windows are cut to 2 pixels beyond the image (nothing further reaches the curvature of an
image pixel); curvature outside the image is computed but must not be counted (``row_image`` and
``col_image`` say where each pixel is).

Measured (scripts/bench_render.py, one 2-core AMD EPYC, one thread): about 3.1 ms of CPU per candidate
for a 684-face bracket in six 320x256 views, against about 6.6 ms through square sphere windows and
:func:`~bop_cender.render.curvature.curvature`.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from bop_cender.render.curvature import curvature_valid
from bop_cender.render.mesh import RenderMesh
from bop_cender.render.raster import DEFAULT_NEAR, camera_vertices, rasterize
from bop_cender.render.resolve import shade
from bop_cender.render.settings import DEFAULT_RENDER_SETTINGS
from bop_cender.render.window import Windows, plan_atlas_chunks

#: Window pixels per chunk on CPU: small enough for the caches, large enough to amortise the per-call
#: overhead of the few hundred torch operations of a chunk (2^18 to 2^20 measured within 5 %).
DEFAULT_CHUNK_PIXELS = DEFAULT_RENDER_SETTINGS.candidate_chunk_pixels_cpu

#: Window pixels beyond the first and last pixel centre the object can cover: 1 for the curvature
#: ring, 1 (forced to background) for the ring's own stencil.
_PAD = 2


@dataclass(frozen=True)
class CurvatureAtlas:
    """Curvature of a chunk of canvases, stacked.

    Attributes:
        canvases: ``(c,)`` int64 indices of the chunk's canvases in the flattened ``(B * V)`` batch.
        curvature: ``(R, w)`` float32 curvature of the atlas (border rows and columns of the atlas left
            out).
        row_canvas: ``(R,)`` int64 position in ``canvases`` of the canvas each atlas row belongs to.
        row_image: ``(R,)`` int64 image row of each atlas row.
        col_image: ``(c,)`` int64 image column of atlas column 0 in each canvas.
    """

    canvases: torch.Tensor
    curvature: torch.Tensor
    row_canvas: torch.Tensor
    row_image: torch.Tensor
    col_image: torch.Tensor


@dataclass(frozen=True)
class CandidateBatch:
    """A batch of candidates prepared for chunked rendering: per-canvas data and the chunk plan.

    Canvas ``c`` is candidate ``c // V`` in view ``c % V``.

    Attributes:
        mesh: the object.
        R, t, K: ``(C, 3, 3)``, ``(C, 3)``, ``(C, 3, 3)`` per canvas.
        verts: ``(3, C, N)`` camera-space vertices.
        lo, extent: ``(C, 2)`` int64 window origin (row, column) and size (rows, columns).
        order: ``(C,)`` canvases by window width.
        chunks: ``(start, stop, width)``: canvases ``order[start:stop]`` rendered together, ``width`` wide.
        near: near plane (mm).
        num_views: V (canvas ``c`` is in view ``c % V``).
        occluder_depth: ``(V, H, W)`` float32 z (mm) of objects already placed in each view, 0 where
            there is none, or None: a candidate pixel behind it is hidden (see :func:`chunk_curvature`).
    """

    mesh: RenderMesh
    R: torch.Tensor
    t: torch.Tensor
    K: torch.Tensor
    verts: torch.Tensor
    lo: torch.Tensor
    extent: torch.Tensor
    order: torch.Tensor
    chunks: list[tuple[int, int, int]]
    near: float
    num_views: int = 1
    occluder_depth: torch.Tensor | None = None


#: A candidate pixel is hidden by a placed object when it lies behind the placed object's surface or
#: within this (mm) in front of it: where the two surfaces coincide, the placed object is what the image
#: shows. So a candidate that duplicates a placed object (the same part found twice: its edges fit the
#: image perfectly) draws nothing there and costs the most, instead of the least; a part resting on a
#: placed one loses only the pixels along the contact. (Hiding only pixels more than 0.5 mm behind let
#: 19 of 453 estimates of a 12-scene oracle run duplicate a placed part.)
OCCLUSION_MARGIN_MM = 0.5


def occluded(depth: torch.Tensor, occluder_depth: torch.Tensor) -> torch.Tensor:
    """Where a surface of depth ``depth`` is hidden by placed objects of depth ``occluder_depth`` (same
    shape, mm, 0: nothing there): both present and the surface behind the occluder or less than
    :data:`OCCLUSION_MARGIN_MM` in front of it. The one rule of the render cost, the two-sided judge and
    the sweeps."""
    return (occluder_depth > 0) & (depth > 0) & (depth > occluder_depth - OCCLUSION_MARGIN_MM)


def prepare_candidates(
    mesh: RenderMesh,
    T_cam_model: torch.Tensor,
    K: torch.Tensor,
    height: int,
    width: int,
    near: float = DEFAULT_NEAR,
    chunk_pixels: int = DEFAULT_CHUNK_PIXELS,
    occluder_depth: torch.Tensor | None = None,
) -> CandidateBatch:
    """Windows and chunk plan of a batch; :func:`chunk_curvature` then renders each chunk.

    Args:
        mesh: the object (on the device of ``T_cam_model``).
        T_cam_model: ``(B, V, 4, 4)`` float32 model-to-camera transforms.
        K: ``(V, 3, 3)`` float32 intrinsics.
        height, width: image size.
        near: near plane (mm).
        chunk_pixels: window pixels per chunk (at least one canvas per chunk).
        occluder_depth: ``(V, H, W)`` float32 depth of already placed objects (0: none), or None.
    """
    B, V = int(T_cam_model.shape[0]), int(T_cam_model.shape[1])
    T = T_cam_model.reshape(B * V, 4, 4)
    R, t = T[:, :3, :3], T[:, :3, 3]
    Kc = K.index_select(0, torch.arange(B * V, device=T.device) % V)
    verts = camera_vertices(mesh, R[:, None], t[:, None])  # (3, BV, N)
    lo, hi = window_bounds(verts, Kc, height, width)
    extent = hi - lo
    order = torch.argsort(extent[:, 1], stable=True)
    chunks = plan_atlas_chunks(extent.index_select(0, order).cpu().tolist(), chunk_pixels)
    if occluder_depth is not None and tuple(occluder_depth.shape) != (V, height, width):
        raise ValueError(f"occluder_depth must be (V, H, W) = {(V, height, width)}, got {tuple(occluder_depth.shape)}")
    return CandidateBatch(mesh, R, t, Kc, verts, lo, extent, order, chunks, near, V, occluder_depth)


def chunk_curvature(batch: CandidateBatch, chunk: tuple[int, int, int]) -> CurvatureAtlas:
    """Render one chunk of a prepared batch and take its curvature (chunks are independent).

    With ``batch.occluder_depth``, candidate pixels behind an already placed object, or less than
    :data:`OCCLUSION_MARGIN_MM` in front of it, become background before the Prewitt gradients: the hidden part of the
    candidate draws no curvature, and the occluder's contour across it is an edge, as in the image.
    """
    start, stop, w = chunk
    canvases = batch.order[start:stop]
    offsets = batch.lo.index_select(0, canvases)
    rows = batch.extent[:, 0].index_select(0, canvases)
    windows = Windows.atlas(offsets, rows, w)
    raster = rasterize(
        batch.mesh,
        batch.R.index_select(0, canvases)[:, None],
        batch.t.index_select(0, canvases)[:, None],
        batch.K.index_select(0, canvases),
        windows,
        batch.near,
        batch.verts.index_select(1, canvases),
    )
    occ = batch.occluder_depth
    buffers = shade(raster, depth=occ is not None, faces=False)
    normals = buffers.normals.view(3, -1, w)
    row_start = windows.start // w
    if occ is not None:
        _hide_occluded(normals, buffers.depth.view(-1, w), occ, canvases % batch.num_views, offsets, rows, row_start)
    normals.index_fill_(1, torch.cat([row_start, row_start + rows - 1]), 0.0)
    curv = curvature_valid(normals[None])[0]  # (R_total - 2, w - 2)
    device = curv.device
    row_canvas = torch.repeat_interleave(torch.arange(canvases.numel(), device=device), rows)
    row_image = torch.arange(row_canvas.numel(), device=device) - row_start.index_select(0, row_canvas)
    row_image += offsets[:, 0].index_select(0, row_canvas)
    return CurvatureAtlas(canvases, curv, row_canvas[1:-1], row_image[1:-1], offsets[:, 1] + 1)


def _hide_occluded(
    normals: torch.Tensor,
    depth: torch.Tensor,
    occluder_depth: torch.Tensor,
    view: torch.Tensor,
    offsets: torch.Tensor,
    rows: torch.Tensor,
    row_start: torch.Tensor,
) -> None:
    """Zero ``normals (3, R, w)`` in place where the atlas ``depth (R, w)`` lies behind ``occluder_depth (V, H, W)``."""
    V, H, W = occluder_depth.shape
    R, w = depth.shape
    device = depth.device
    row_canvas = torch.repeat_interleave(torch.arange(rows.numel(), device=device), rows)
    img_row = (
        torch.arange(R, device=device)
        - row_start.index_select(0, row_canvas)
        + offsets[:, 0].index_select(0, row_canvas)
    )
    img_col = offsets[:, 1].index_select(0, row_canvas)[:, None] + torch.arange(w, device=device)
    inside = ((img_row >= 0) & (img_row < H))[:, None] & (img_col >= 0) & (img_col < W)
    flat = (view.index_select(0, row_canvas)[:, None] * H + img_row.clamp(0, H - 1)[:, None]) * W + img_col.clamp(
        0, W - 1
    )
    occ = occluder_depth.reshape(-1).index_select(0, flat.reshape(-1)).view(R, w)
    hidden = inside & occluded(depth, occ)
    normals.masked_fill_(hidden[None], 0.0)


def window_bounds(verts: torch.Tensor, K: torch.Tensor, height: int, width: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Window first pixel ``(C, 2)`` and one-past-last pixel ``(C, 2)`` (row, column), int64.

    From the projected vertices' bounding box, padded by ``_PAD`` and cut to 2 pixels beyond the image.
    Vertices behind the camera project far away: the window then spans the whole image.

    Args:
        verts: ``(3, C, N)`` camera-space vertices.
        K: ``(C, 3, 3)`` intrinsics.
    """
    z = verts[2].clamp_min(1e-3)
    x = (K[:, 0, 0, None] * verts[0] + K[:, 0, 1, None] * verts[1]) / z + K[:, 0, 2, None]
    y = K[:, 1, 1, None] * verts[1] / z + K[:, 1, 2, None]
    limit = float(4 * max(height, width) + 16)
    # Pixel centres u + 0.5 within [min, max]: u from ceil(min - 0.5) to floor(max - 0.5).
    lo = torch.stack([y.amin(-1), x.amin(-1)], -1).clamp(-limit, limit).sub(0.5).ceil().to(torch.int64) - _PAD
    hi = torch.stack([y.amax(-1), x.amax(-1)], -1).clamp(-limit, limit).sub(0.5).floor().to(torch.int64) + _PAD + 1
    size = torch.tensor([height, width], device=lo.device)
    lo = lo.clamp_min(-2)
    hi = torch.minimum(hi, size + 2)
    hi = torch.maximum(hi, lo + 3)  # at least one interior pixel, even for objects outside the image
    return lo, hi
