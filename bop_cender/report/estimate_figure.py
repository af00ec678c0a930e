"""A scene's figure drawn from its results rows and its images alone, for a report of a run made without ``--vis``.

``run --vis`` draws what every stage saw (:mod:`bop_cender.report.scene_figure`), which needs the network's heatmaps;
re-running the network for a report would cost as much as the run. This figure needs only what a results file and
its data hold: each target image of the scene with the outlines of the rows' poses, coloured by the scorer's own
verdict (:mod:`bop_cender.report.breakdown`): green a row matched at the strictest MSSD threshold (5 % of the
diameter), red one that is not, yellow one left out (BOP'24: its instance is under 10 % visible), cyan a counted GT
instance no row matched there.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from bop_cender.eval.ground_truth import ImageGt
from bop_cender.meshes import MeshCache
from bop_cender.render.rasterizer import render_scene
from bop_cender.report.breakdown import LEFT_OUT, RIGHT, WRONG
from bop_cender.report.png import pyplot, save_png
from bop_cender.report.scene_figure import MISSED, UNJUDGED, crop_box, outline
from bop_cender.report.scene_figure import RIGHT as GREEN
from bop_cender.report.scene_figure import WRONG as RED

#: Outline colour of each verdict (RGB in [0, 1]); the run's figures use the same green, red and cyan.
COLOURS = {RIGHT: GREEN, WRONG: RED, LEFT_OUT: UNJUDGED}
#: At most this many images of a scene are drawn (its first target images): a 5-view group fits one row.
MAX_IMAGES = 6


@dataclass(frozen=True)
class Outline:
    """One pose to outline in one image: its object, its model-to-camera pose (mm) and its colour."""

    obj_id: int
    T_cam_model: np.ndarray
    colour: tuple[float, float, float]


@dataclass(frozen=True)
class Panel:
    """One image of the figure: its ground truth (intrinsics, size), its pixels (None: drawn black) and outlines."""

    image: ImageGt
    rgb: np.ndarray | None
    outlines: Sequence[Outline]


def panel_masks(panel: Panel, meshes: MeshCache) -> np.ndarray:
    """``(H, W)`` int64: the index into ``panel.outlines`` of the pose seen at each pixel (the poses hide each
    other, as the objects would), -1 where none; one render of the image's poses together."""
    im = panel.image
    if not panel.outlines:
        return np.full((im.height, im.width), -1, dtype=np.int64)
    T = torch.as_tensor(np.stack([o.T_cam_model for o in panel.outlines])[None], dtype=torch.float32)
    K = torch.as_tensor(im.K[None], dtype=torch.float32)
    return render_scene([meshes(o.obj_id) for o in panel.outlines], T, K, im.height, im.width).instance[0].numpy()


def draw_outlines(rgb: np.ndarray, instance: np.ndarray, outlines: Sequence[Outline]) -> np.ndarray:
    """``rgb (H, W, 3)`` uint8 as float in [0, 1] with each pose's outline painted in its colour (missed GTs first,
    so that a row's outline over the same part stays visible)."""
    overlay = rgb.astype(np.float32) / 255.0
    order = sorted(range(len(outlines)), key=lambda k: outlines[k].colour != MISSED)
    for k in order:
        overlay[outline(instance == k)] = outlines[k].colour
    return overlay


def estimate_figure(scene_key: str, panels: Sequence[Panel], meshes: MeshCache, title: str, path: Path) -> Path:
    """Write the figure of one scene (one column per panel, each cropped to its parts) to ``path`` (PNG, atomically)."""
    plt = pyplot()

    panels = list(panels)[:MAX_IMAGES]
    n = max(1, len(panels))
    H, W = (panels[0].image.height, panels[0].image.width) if panels else (1, 1)
    panel = max(2.4, 5.0 / n)  # inches per panel: a scene of one or two images is not drawn as a thumbnail
    fig, axes = plt.subplots(1, n, figsize=(panel * n, panel * H / W + 0.7), squeeze=False)
    for ax, panel in zip(axes[0], panels, strict=False):
        im = panel.image
        instance = panel_masks(panel, meshes)
        rgb = panel.rgb if panel.rgb is not None else np.zeros((im.height, im.width, 3), np.uint8)
        top, left, h, w = crop_box(instance >= 0, np.zeros((0, 2)))
        ax.imshow(draw_outlines(rgb, instance, panel.outlines)[top : top + h, left : left + w])
        ax.set_title(f"image {im.im_id}", fontsize=7)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    if not panels:
        axes[0, 0].text(0.5, 0.5, "no image of this scene is evaluated", ha="center", va="center", fontsize=7)
    fig.suptitle(title, fontsize=8)
    return save_png(fig, path, dpi=90)


def scene_panels(
    images: Sequence[ImageGt],
    rows_by_image: Mapping[tuple[int, int], Sequence],
    verdicts_rows: Mapping[int, str],
    missed: Mapping[tuple[int, int], set[int]],
    rgb_of: Mapping[tuple[int, int], Path | None],
    read_rgb,
) -> list[Panel]:
    """The panels of a scene's images: per image the rows the scorer evaluated (by their line's verdict) and the
    counted GT instances it found no match for; ``read_rgb(path)`` gives an image's pixels (None: unreadable)."""
    panels = []
    for im in images[:MAX_IMAGES]:
        outlines = [
            Outline(g.obj_id, g.T_cam_model, MISSED) for g in im.instances if g.gt_id in missed.get(im.key, set())
        ]
        for row in rows_by_image.get(im.key, ()):
            verdict = verdicts_rows.get(row.line)
            if verdict is None:
                continue  # not evaluated (beyond the top-n cut, or not a target): no verdict to draw
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = row.R, row.t
            outlines.append(Outline(row.obj_id, T, COLOURS[verdict]))
        path = rgb_of.get(im.key)
        panels.append(Panel(im, None if path is None else read_rgb(path), outlines))
    return panels
