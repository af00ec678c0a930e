"""Depth of many poses of one mesh in tight windows, cut to their silhouettes inside the image.

VSD needs only depth, only inside the image, only where the object is. Square windows sized from the
bounding sphere (:func:`~bop_cender.render.rasterizer.render_candidates`) waste most of their pixels on
elongated or off-centre objects; here every pose gets the smallest window that holds the pixel centres
its projected vertices can cover (plus one pixel of margin against rounding), cut to the image, and
the windows of a chunk of poses are stacked into one atlas of a common width
(:meth:`~bop_cender.render.window.Windows.atlas`), poses taken in order of window width, as the cost
function's path does (:mod:`bop_cender.render.candidate_curvature`).

Exactness: the rasteriser works in full-image pixel coordinates, the z-buffer's depth quantisation is
per canvas and shading evaluates each face's ``1/z`` plane at the pixel centre, so a pixel's depth does
not depend on the window layout; a triangle covers only pixel centres inside the bounding box of its
projected corners, which the window holds. Every depth pixel inside the image is therefore the one
:func:`~bop_cender.render.rasterizer.render_candidates` gives, bit for bit.

A pose with a vertex before the near plane (whose projection then does not bound its silhouette) gets
the whole image as its window: still exact, only slower; callers render such poses full-frame anyway.
"""

from __future__ import annotations

import numpy as np
import torch

from bop_cender.render.mesh import RenderMesh
from bop_cender.render.raster import DEFAULT_NEAR, camera_vertices, project_vertices, rasterize
from bop_cender.render.resolve import shade
from bop_cender.render.settings import DEFAULT_RENDER_SETTINGS
from bop_cender.render.window import Windows, plan_atlas_chunks

#: Atlas pixels per rasteriser call (at least one pose per call).
DEFAULT_CHUNK_PIXELS = DEFAULT_RENDER_SETTINGS.depth_crop_chunk_pixels

#: Window pixels kept beyond the first and last pixel centre the projected vertices can cover.
_MARGIN = 1

__all__ = ["DEFAULT_CHUNK_PIXELS", "crop_to_silhouette", "tight_depth_crops"]


def tight_depth_crops(
    mesh: RenderMesh,
    T_cam_model: np.ndarray,
    K: np.ndarray,
    height: int,
    width: int,
    near: float = DEFAULT_NEAR,
    chunk_pixels: int = DEFAULT_CHUNK_PIXELS,
) -> tuple[list[np.ndarray], np.ndarray]:
    """Render one mesh in E poses and cut each depth map to its silhouette's bounding box inside the image.

    Args:
        mesh: the object (CPU).
        T_cam_model: ``(E, 4, 4)`` model-to-camera poses (mm).
        K: ``(E, 3, 3)`` intrinsics, one per pose.
        height, width: image size; pixels outside it are dropped.
        near: near plane (mm).
        chunk_pixels: atlas pixels per rasteriser call.

    Returns:
        E crops ``(h_e, w_e)`` float32 (z in mm, 0 on background; ``(0, 0)`` when no pixel of the pose
        is inside the image) and their origins ``(E, 2)`` int64 (row, column of the first pixel).
    """
    E = int(np.shape(T_cam_model)[0])
    crops: list[np.ndarray] = [np.zeros((0, 0), np.float32)] * E
    origin = np.zeros((E, 2), dtype=np.int64)
    if E == 0 or mesh.vertices.shape[0] == 0:
        return crops, origin
    T = torch.as_tensor(np.asarray(T_cam_model)).to(torch.float32).reshape(E, 4, 4)
    Ks = torch.as_tensor(np.asarray(K)).to(torch.float32).reshape(E, 3, 3)
    verts = camera_vertices(mesh, T[:, None, :3, :3], T[:, None, :3, 3])  # (3, E, N)
    lo, hi = _windows(verts, Ks, height, width, near)
    extent = hi - lo  # (E, 2)
    visible = np.flatnonzero((extent > 0).all(1))
    order = visible[np.argsort(extent[visible, 1], kind="stable")]
    for start, stop, w in plan_atlas_chunks(extent[order].tolist(), chunk_pixels):
        idx = order[start:stop]
        rows = extent[idx, 0]
        windows = Windows.atlas(torch.from_numpy(lo[idx]), torch.from_numpy(rows), w)
        sel = torch.from_numpy(idx)
        # Rotation and translation as strided views of (c, 4, 4) poses, as render_candidates passes them:
        # the vertex transform's matmul rounds differently for contiguous (c, 3, 3) rotations.
        Tc = T.index_select(0, sel)
        raster = rasterize(
            mesh, Tc[:, None, :3, :3], Tc[:, None, :3, 3], Ks.index_select(0, sel), windows, near, normals=False
        )
        depth = shade(raster, depth=True, normals=False, faces=False).depth
        atlas = depth.view(-1, w).numpy()  # (sum of rows, w)
        ends = np.cumsum(rows)
        for k, e in enumerate(idx.tolist()):
            window = atlas[ends[k] - rows[k] : ends[k], : extent[e, 1]]
            crops[e], origin[e] = crop_to_silhouette(window, lo[e])
    return crops, origin


def _windows(
    verts: torch.Tensor, K: torch.Tensor, height: int, width: int, near: float
) -> tuple[np.ndarray, np.ndarray]:
    """First pixel ``(E, 2)`` and one-past-last pixel ``(E, 2)`` (row, column) int64 of each pose's window.

    From the bounding box of the vertices' projections (as the rasteriser projects them), widened by
    ``_MARGIN`` and cut to the image; an empty window (``hi <= lo``) for a pose wholly outside it; the
    whole image for a pose with a vertex before the near plane.

    Args:
        verts: ``(3, E, N)`` camera-space vertices.
        K: ``(E, 3, 3)`` intrinsics.
    """
    x, y = project_vertices(verts, K, near)  # (E, N) each
    limit = float(4 * max(height, width) + 16)
    # Pixel centres u + 0.5 within [min, max]: u from ceil(min - 0.5) to floor(max - 0.5).
    first = torch.stack([y.amin(-1), x.amin(-1)], -1).double().clamp(-limit, limit).sub(0.5).ceil()
    last = torch.stack([y.amax(-1), x.amax(-1)], -1).double().clamp(-limit, limit).sub(0.5).floor()
    lo = first.to(torch.int64).numpy() - _MARGIN
    hi = last.to(torch.int64).numpy() + _MARGIN + 1
    size = np.array([height, width], dtype=np.int64)
    lo, hi = np.clip(lo, 0, size), np.clip(hi, 0, size)
    clipped = (verts[2].amin(-1) < near).numpy()
    lo[clipped], hi[clipped] = 0, size
    return lo, hi


def crop_to_silhouette(window: np.ndarray, lo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cut one window's depth ``(h, w)`` (first pixel at image ``lo (2,)``) to its silhouette's bounding box."""
    rows = np.flatnonzero(window.any(axis=1))
    if rows.size == 0:
        return np.zeros((0, 0), np.float32), np.zeros(2, np.int64)
    cols = np.flatnonzero(window.any(axis=0))
    crop = np.ascontiguousarray(window[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1], dtype=np.float32)
    return crop, np.array([lo[0] + rows[0], lo[1] + cols[0]], dtype=np.int64)
