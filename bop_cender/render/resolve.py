"""Shade a z-buffer: per-pixel camera-space normals, depth and face ids from the winning faces.

Only covered pixels are computed: for each, the winner's table row gives the perspective-correct
interpolated normal ``M @ (x, y, 1)`` (normalised here) and ``z = 1 / (a x + b y + c)`` at the pixel
centre ``(x, y) = (u + 0.5, v + 0.5)`` in full-image coordinates, so a window and the full frame give
bit-identical values at the same pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from bop_cender.render.raster import Raster


@dataclass(frozen=True)
class WindowMaps:
    """Per-pixel outputs of a batch of canvases (``C`` canvases, windows of ``h x w``).

    Attributes:
        mask: ``(C, h, w)`` bool, covered pixels.
        face: ``(C, h, w)`` int64 face index of the rendered mesh (packed meshes: packed index), -1 on
            background; None if not asked for.
        depth: ``(C, h, w)`` float32 z in mm (not distance), 0 on background; None if not asked for.
        normals: ``(C, h, w, 3)`` float32 camera-space unit normals, 0 on background; None if not asked
            for.
    """

    mask: torch.Tensor
    face: torch.Tensor | None
    depth: torch.Tensor | None
    normals: torch.Tensor | None


@dataclass(frozen=True)
class Buffers:
    """Flat per-buffer-pixel outputs (any window layout).

    Attributes:
        face: ``(total,)`` int64 face index, -1 on background, or None.
        depth: ``(total,)`` float32 z (mm), 0 on background, or None.
        normals: ``(3, total)`` float32 unit normals as 3 channel planes over the whole buffer, 0 on
            background; or None.
    """

    face: torch.Tensor | None
    depth: torch.Tensor | None
    normals: torch.Tensor | None


def resolve(raster: Raster, depth: bool = True, normals: bool = True, faces: bool = True) -> WindowMaps:
    """Turn a :class:`~bop_cender.render.raster.Raster` with uniform windows into per-pixel maps.

    Args:
        raster: the z-buffer (windows of one height h, as :meth:`Windows.uniform` makes).
        depth, normals, faces: which maps to compute (the others are None; ``mask`` always).
    """
    windows = raster.windows
    C, w = windows.num_canvases, windows.width
    h = windows.total // max(1, C * w)
    buffers = shade(raster, depth, normals, faces)
    depth_map = None if buffers.depth is None else buffers.depth.view(C, h, w)
    face_map = None if buffers.face is None else buffers.face.view(C, h, w)
    normal_map = None
    if buffers.normals is not None:
        planes = buffers.normals.view(3, C, h, w)
        normal_map = planes.permute(1, 2, 3, 0).contiguous()
    return WindowMaps(raster.keys.view(C, h, w) >= 0, face_map, depth_map, normal_map)


def shade(raster: Raster, depth: bool = True, normals: bool = True, faces: bool = True) -> Buffers:
    """Compute face ids, depth and normals at the covered pixels and write them into flat buffers."""
    device, dtype = raster.keys.device, raster.table.dtype
    total = raster.windows.total
    pix = raster.pix
    out_face = out_depth = out_normals = None
    if faces:
        face_id = raster.face_index.index_select(0, raster.pix_row)
        out_face = torch.full((total,), -1, dtype=torch.int64, device=device).scatter_(0, pix, face_id)
    if not (depth or normals):
        return Buffers(out_face, None, None)
    table, row = raster.table, raster.pix_row
    x, y = raster.pix_x, raster.pix_y
    if depth:
        a, b, c = (table[k].index_select(0, row) for k in (9, 10, 11))
        z = torch.addcmul(c, a, x).addcmul_(b, y).reciprocal_()
        out_depth = torch.zeros(total, dtype=dtype, device=device).scatter_(0, pix, z)
    if normals:
        n = [
            torch.addcmul(table[3 * a + 2].index_select(0, row), table[3 * a].index_select(0, row), x).addcmul_(
                table[3 * a + 1].index_select(0, row), y
            )
            for a in range(3)
        ]
        inv = (n[0] * n[0]).addcmul_(n[1], n[1]).addcmul_(n[2], n[2]).clamp_min_(1e-30).rsqrt_()
        out_normals = torch.zeros((3, total), dtype=dtype, device=device)
        for a in range(3):
            out_normals[a].scatter_(0, pix, n[a].mul_(inv))
    return Buffers(out_face, out_depth, out_normals)
