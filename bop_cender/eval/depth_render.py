"""The evaluation's seam to the one batched renderer (:mod:`bop_cender.render`): depth and instance maps.

VSD needs the depth of a model in the estimated and in the GT pose; it comes from our renderer (no OpenGL),
through the few functions here, so that a change of the renderer's API touches only this file. (DIMO's
targets need which object is in front at each pixel of the whole pile: :mod:`bop_cender.visibility`.)

Renders for VSD are cut right away to the bounding box of their silhouette inside the image
(:class:`~bop_cender.eval.render_crops.DepthCrops`): VSD only looks at pixels where either render is non-zero, so a crop loses
nothing, and 1,000 renders of a few thousand pixels each stay small in memory. Poses are rendered in
tight windows from their projected vertices (:mod:`bop_cender.render.depth_crops`), bit-identical to
the square windows of :func:`~bop_cender.render.rasterizer.render_candidates` at every image pixel;
poses whose bounding sphere reaches the near plane are rendered full-frame.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import torch

from bop_cender.eval.render_crops import DepthCrops
from bop_cender.render.depth_crops import crop_to_silhouette, tight_depth_crops
from bop_cender.render.mesh import RenderMesh
from bop_cender.render.raster import DEFAULT_NEAR
from bop_cender.render.rasterizer import render_objects_separately

#: Poses rendered per renderer call (bounded memory; measured fastest on 2 cores).
CHUNK = 48

__all__ = [
    "CHUNK",
    "render_depth_crops",
    "single_threaded_torch",
]


@contextmanager
def single_threaded_torch() -> Iterator[None]:
    """One torch intra-op thread inside the block (restored after): callers parallelise over threads themselves."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def render_depth_crops(
    mesh: RenderMesh, T_cam_model: np.ndarray, K: np.ndarray, height: int, width: int, chunk: int = CHUNK
) -> DepthCrops:
    """Render one mesh in E poses (each with its own intrinsics) and crop each render to its silhouette.

    Args:
        mesh: the model.
        T_cam_model: ``(E, 4, 4)`` model-to-camera poses (mm).
        K: ``(E, 3, 3)`` intrinsics.
        height, width: image size; pixels outside it are dropped.
        chunk: poses per full-frame renderer call (poses whose bounding sphere reaches the near plane).
    """
    T = np.asarray(T_cam_model, dtype=np.float64).reshape(-1, 4, 4)
    Ks = np.broadcast_to(np.asarray(K, dtype=np.float64), (len(T), 3, 3))
    E = len(T)
    crops: list[np.ndarray] = [np.zeros((0, 0), np.float32)] * E
    origin = np.zeros((E, 2), dtype=np.int64)
    if E == 0:
        return DepthCrops(crops, origin)
    near_hit = T[:, 2, 3] - mesh.radius <= DEFAULT_NEAR  # the projected vertices bound the silhouette otherwise
    windowed = np.flatnonzero(~near_hit)
    if windowed.size:
        tight, tight_origin = tight_depth_crops(mesh, T[windowed], Ks[windowed], height, width)
        for k, e in enumerate(windowed.tolist()):
            crops[e] = tight[k]
        origin[windowed] = tight_origin
    full = np.flatnonzero(near_hit)
    for start in range(0, len(full), chunk):
        idx = full[start : start + chunk]
        r = render_objects_separately([mesh], T[idx, None], Ks[idx], height, width)
        depth = r.depth[:, 0].cpu().numpy()
        for k, e in enumerate(idx):
            crops[e], origin[e] = crop_to_silhouette(depth[k], np.zeros(2, np.int64))
    return DepthCrops(crops, origin)
