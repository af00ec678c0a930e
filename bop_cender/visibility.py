"""Visible fractions of posed objects, rendered: the one computation, for the synthetic writers and evaluation.

``visib_fract = px_count_visib / px_count_all`` as the toolkit's ``calc_gt_info.py`` defines it: the pixels
where the instance is the front-most surface inside the image, over the pixels of its whole silhouette
rendered alone, parts beyond the image border included (the toolkit counts on a larger canvas). Our renders
are exact, so "front-most" is the instance map of the whole pile, not a depth test with a tolerance.

Used where no ``scene_gt_info.json`` exists (DIMO's targets, :mod:`bop_cender.eval.visibility`) and where one
is written (the regression fixture, :mod:`bop_cender.synth.regression_fixture`). It sits above the renderer
and below both users (synth must not import eval). :mod:`bop_cender.synth.gt_info` writes the full
``scene_gt_info`` entries (boxes, masks, valid pixels) from a 3x canvas render and uses the same ratio.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from bop_cender.render.mesh import RenderMesh
from bop_cender.render.rasterizer import render_candidates, render_scene

#: Poses rendered per renderer call for the silhouette areas (bounded memory), as the VSD renders use.
CHUNK = 48


@dataclass(frozen=True)
class PileVisibility:
    """Pixel counts of C instances in V views.

    Attributes:
        visible: ``(V, C)`` int64 pixels where the instance is in front, inside the image (``px_count_visib``).
        total: ``(V, C)`` int64 pixels of its whole silhouette (``px_count_all``).
    """

    visible: np.ndarray
    total: np.ndarray

    @property
    def fract(self) -> np.ndarray:
        """``(V, C)`` float64 visible fraction, 0 where the silhouette is empty."""
        return visib_fract(self.visible, self.total)


def visib_fract(visible: np.ndarray, total: np.ndarray) -> np.ndarray:
    """``visible / total``, 0 where ``total`` is 0 (the toolkit's ``visib_fract``)."""
    visible, total = np.asarray(visible), np.asarray(total)
    return np.where(total > 0, visible / np.maximum(total, 1), 0.0)


def pile_visibility(
    meshes: Sequence[RenderMesh],
    T_cam_model: np.ndarray,
    K: np.ndarray,
    height: int,
    width: int,
    counted: int | None = None,
) -> PileVisibility:
    """Visible and total pixels of the first ``counted`` instances of a pile (the rest only occlude).

    Args:
        meshes: M meshes, one per instance (repeat a mesh for repeated objects), occluders last.
        T_cam_model: ``(V, M, 4, 4)`` poses of every instance in every view.
        K: ``(V, 3, 3)`` intrinsics.
        height, width: image size.
        counted: how many instances get counts (default all M).
    """
    T = np.asarray(T_cam_model, dtype=np.float64)
    V = T.shape[0]
    C = len(meshes) if counted is None else counted
    instance = render_pile_instances(meshes, T, K, height, width)
    visible = np.stack([(instance == m).reshape(V, -1).sum(axis=1) for m in range(C)], axis=1)
    total = np.zeros_like(visible)
    for m in range(C):
        total[:, m] = silhouette_areas(meshes[m], T[:, m], K, height, width)
    return PileVisibility(visible, total)


def render_pile_instances(
    meshes: Sequence[RenderMesh], T_cam_model: np.ndarray, K: np.ndarray, height: int, width: int
) -> np.ndarray:
    """Which object is in front at each pixel: ``(V, H, W)`` int64 index into ``meshes``, -1 background.

    Args:
        meshes: M meshes, one per object instance (repeat a mesh for repeated objects).
        T_cam_model: ``(V, M, 4, 4)`` poses of every object in every view.
        K: ``(V, 3, 3)`` intrinsics.
    """
    with torch.no_grad():
        r = render_scene(list(meshes), np.asarray(T_cam_model, np.float64), np.asarray(K, np.float64), height, width)
    return r.instance.cpu().numpy()


def silhouette_areas(mesh: RenderMesh, T_cam_model: np.ndarray, K: np.ndarray, height: int, width: int) -> np.ndarray:
    """Pixel count ``(E,)`` of the whole silhouette of each pose, parts beyond the image border included.

    The toolkit's ``calc_gt_info.py`` counts ``px_count_all`` on a larger canvas for the same reason:
    a truncated object's visible fraction is its visible pixels over its whole silhouette.
    """
    T = np.asarray(T_cam_model, dtype=np.float64).reshape(-1, 4, 4)
    Ks = np.broadcast_to(np.asarray(K, dtype=np.float64), (len(T), 3, 3))
    out = np.zeros(len(T), dtype=np.int64)
    for start in range(0, len(T), CHUNK):
        idx = np.arange(start, min(len(T), start + CHUNK))
        r = render_candidates(mesh, T[None, idx], Ks[idx], height, width, depth=False)
        out[idx] = r.mask[0].reshape(len(idx), -1).sum(dim=1).cpu().numpy()
    return out
