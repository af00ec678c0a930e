"""BOP ``scene_gt_info.json`` entries, full and visible masks, computed with the batched renderer.

Definitions follow the BOP toolkit's ``calc_gt_info.py`` (docs/datasets.md): ``px_count_all`` counts the
object's silhouette rendered alone on a canvas 3x larger than the image (the image in its centre), so
truncated parts count too; ``bbox_obj`` is that silhouette's box in image coordinates (it may start outside
the image); ``px_count_visib`` counts the pixels where the object is the front-most surface (our renders are
exact, so visibility is the instance map instead of a depth test with a tolerance); ``px_count_valid`` counts
silhouette pixels inside the image with non-zero test depth; ``visib_fract = px_count_visib / px_count_all``;
boxes are ``[x, y, w, h]`` and ``[-1, -1, -1, -1]`` when empty.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bop_cender.render.mesh import RenderMesh
from bop_cender.render.rasterizer import render_objects_separately


@dataclass
class ObjectVisibility:
    """Per-object masks and the ``scene_gt_info`` entry of one image.

    Attributes:
        mask: ``(H, W)`` bool full silhouette inside the image.
        mask_visib: ``(H, W)`` bool visible part.
        info: the BOP ``scene_gt_info`` dict for this object in this image.
    """

    mask: np.ndarray
    mask_visib: np.ndarray
    info: dict


def _bbox(mask: np.ndarray, dx: int = 0, dy: int = 0) -> list[int]:
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return [-1, -1, -1, -1]
    x0, y0 = int(xs.min()), int(ys.min())
    return [x0 - dx, y0 - dy, int(xs.max()) - x0 + 1, int(ys.max()) - y0 + 1]


def object_visibility(
    meshes: Sequence[RenderMesh],
    T_cam_model: np.ndarray,
    K: np.ndarray,
    instance: np.ndarray,
    depth: np.ndarray,
    object_indices: Sequence[int],
) -> list[ObjectVisibility]:
    """Masks and ``scene_gt_info`` entries of the listed objects in one view.

    Args:
        meshes: all M render meshes of the scene (occluders included).
        T_cam_model: ``(M, 4, 4)`` poses in this camera.
        K: ``(3, 3)`` intrinsics.
        instance: ``(H, W)`` the scene render's instance map (index into meshes, -1 background).
        depth: ``(H, W)`` the test depth (mm, 0 = missing).
        object_indices: which meshes get an entry (the GT objects, in scene_gt order).
    """
    H, W = instance.shape
    K_big = np.asarray(K, dtype=np.float64).copy()
    K_big[0, 2] += W
    K_big[1, 2] += H
    sel = [meshes[i] for i in object_indices]
    T_sel = np.asarray(T_cam_model)[list(object_indices)][None]  # (1, m, 4, 4)
    big = render_objects_separately(sel, T_sel, K_big[None], 3 * H, 3 * W).mask[0].numpy()  # (m, 3H, 3W)
    out = []
    for k, idx in enumerate(object_indices):
        full_big = big[k]
        mask = full_big[H : 2 * H, W : 2 * W]
        # Visible pixels are the scene render's pixels of the object that its own render covers too: the two
        # renders can differ by a pixel along an edge shared with another part, and a visible pixel outside
        # the object's own mask would make visib_fract exceed 1 (which the loaders refuse, as for real data).
        visib = (instance == idx) & mask
        px_all = int(full_big.sum())
        px_visib = int(visib.sum())
        info = {
            "bbox_obj": _bbox(full_big, dx=W, dy=H),
            "bbox_visib": _bbox(visib),
            "px_count_all": px_all,
            "px_count_valid": int((mask & (depth > 0)).sum()),
            "px_count_visib": px_visib,
            "visib_fract": float(px_visib / px_all) if px_all > 0 else 0.0,
        }
        out.append(ObjectVisibility(mask=mask, mask_visib=visib, info=info))
    return out
