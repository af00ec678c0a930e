"""One image size for every view of a scene: what the method needs of a multi-sensor capture.

The method stacks a scene's views (heatmaps ``(V, C, H, W)``, stage 3's renders over all views at one size), while a
BOP-Industrial capture mixes cameras of different resolutions (:mod:`bop_cender.data.industrial`). :func:`on_one_canvas`
is the one place where they meet: every view whose size differs from the scene's evaluated view (the first view
where none is marked) is seen at that size, its intrinsics scaled with it (``K' = diag(sx, sy, 1) K``: continuous image
points scale with the image, pixel centres at ``u + 0.5``, as ``cv2.resize`` samples), its image resampled when read
(:func:`read_view_rgb`). The evaluated views are untouched, so results rows, written in their cameras, are unchanged.
A scene whose views share one size is returned as it is.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from bop_cender.data.bop_io import load_rgb
from bop_cender.data.types import CameraView, Scene

#: ``CameraView.info`` key of a view seen at another size than its image's: the image's ``(width, height)``.
RESAMPLED_FROM = "resampled_from"


def on_one_canvas(scene: Scene) -> Scene:
    """``scene`` with every view at the size of its first evaluated view (module docstring)."""
    reference = next((v for v in scene.views if v.evaluated), scene.views[0]) if scene.views else None
    if reference is None or all((v.width, v.height) == (reference.width, reference.height) for v in scene.views):
        return scene
    W, H = reference.width, reference.height
    return replace(scene, views=tuple(_resized(v, W, H) for v in scene.views))


def _resized(view: CameraView, W: int, H: int) -> CameraView:
    if (view.width, view.height) == (W, H):
        return view
    scale = np.diag([W / view.width, H / view.height, 1.0])
    info = {**view.info, RESAMPLED_FROM: (view.width, view.height)}
    return replace(view, K=scale @ view.K, width=W, height=H, info=info)


def read_view_rgb(view: CameraView) -> np.ndarray:
    """The view's colour image ``(H, W, 3)`` uint8 RGB (a gray image's channel repeated), resampled to the view's size
    where :func:`on_one_canvas` changed it (area-averaged when smaller, bilinear when larger)."""
    import cv2

    image = load_rgb(view.rgb_path)
    if RESAMPLED_FROM in view.info and image.shape[:2] != (view.height, view.width):
        shrink = view.width < image.shape[1]
        image = cv2.resize(
            image, (view.width, view.height), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR
        )
    return image
