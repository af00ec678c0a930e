"""Per-scene figure of a run (``bop-cender run --vis DIR``): what each stage saw and produced, and which poses are right.

Columns are views; rows are the input image, the center heatmap with the detected 3D centres projected (red
crosses; GT centres as green circles), the curvature heatmap, and the input with the outlines of the estimated
models, each coloured by its verdict where the scene is annotated: green for a pose within the paper's strict
figure (MSSD under 5 % of the object's diameter, symmetries included: :func:`judge_estimates`), red for one that is
not, and cyan for a GT part that no estimate matches (yellow: estimates of a scene without GT).

Each column shows the part of its view where the objects are (:func:`crop_box`: the GT and estimated parts and
the centres, with a margin, at the image's aspect ratio), the same crop in all four rows: piles fill a fifth of a
T-LESS-layout view, and one-pixel outlines of a whole 720 x 540 view shrunk into a panel were not legible.
"""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from bop_cender.data.types import ObjectModel, Scene
from bop_cender.eval.model_points import eval_vertices
from bop_cender.eval.pose_errors import hull_vertices, mssd
from bop_cender.geometry.camera import project_points
from bop_cender.geometry.poses import transform_points
from bop_cender.render.mesh import RenderMesh
from bop_cender.render.rasterizer import render_scene
from bop_cender.report.png import pyplot, save_png

TITLE_CHARS_PER_INCH = 13
"""How many characters of the 8-point title fit an inch of the figure: a narrow figure (one or two views) wraps its
title instead of cutting it."""

MSSD_FRACTION = 0.05
"""A pose is right when its MSSD is under this fraction of the object's diameter (the paper's AR_MSSD<5%)."""

RIGHT, WRONG, MISSED, UNJUDGED = (0.1, 0.9, 0.1), (1.0, 0.1, 0.1), (0.0, 0.9, 1.0), (1.0, 0.85, 0.0)
"""Outline colours (RGB in [0, 1]): a right estimate, a wrong one, a GT part no estimate matches, an estimate of a
scene without GT."""


@dataclass(frozen=True)
class Verdicts:
    """Which estimates are right and which GT parts they find (:func:`judge_estimates`).

    Attributes:
        estimate_right: per estimate, True where it matches a GT part.
        gt_found: per GT part, True where an estimate matches it.
        errors_mm: per estimate, the MSSD (mm) to the GT part it matches, else to the nearest GT part of its id
            (``inf``: none).
    """

    estimate_right: tuple[bool, ...]
    gt_found: tuple[bool, ...]
    errors_mm: tuple[float, ...]


def judge_estimates(
    estimates: Sequence[tuple[int, np.ndarray]],
    gt: Sequence[tuple[int, np.ndarray]],
    models: Mapping[int, ObjectModel],
    fraction: float = MSSD_FRACTION,
) -> Verdicts:
    """One-to-one verdicts of ``estimates`` against ``gt`` (each a list of ``(obj_id, T (4, 4))`` in one frame, mm).

    Pairs of the same object id are taken by increasing MSSD (symmetries included, as the scorer), each estimate
    and each GT part at most once; a pair matches when its MSSD is under ``fraction`` of the diameter. Greedy
    matching by error is what BOP's per-image matching does by score, close enough for a figure that says which
    outline is which."""
    errors = np.full((len(estimates), len(gt)), np.inf)
    for obj_id in {i for i, _ in estimates} & {i for i, _ in gt}:
        e_idx = [k for k, (i, _) in enumerate(estimates) if i == obj_id]
        g_idx = [k for k, (i, _) in enumerate(gt) if i == obj_id]
        model = models[obj_id]
        sym_R, sym_t = model.symmetry_transforms()
        E = np.stack([estimates[k][1] for k in e_idx])[:, None].repeat(len(g_idx), 1).reshape(-1, 4, 4)
        G = np.stack([gt[k][1] for k in g_idx])[None].repeat(len(e_idx), 0).reshape(-1, 4, 4)
        err = mssd(E[:, :3, :3], E[:, :3, 3], G[:, :3, :3], G[:, :3, 3], hull_vertices(eval_vertices(model)),
                   sym_R, sym_t)  # fmt: skip
        errors[np.ix_(e_idx, g_idx)] = err.reshape(len(e_idx), len(g_idx))
    right, found = [False] * len(estimates), [False] * len(gt)
    matched_error = errors.min(1, initial=np.inf)
    for flat in np.argsort(errors, axis=None, kind="stable"):
        e, g = divmod(int(flat), max(1, len(gt)))
        if not np.isfinite(errors[e, g]):
            break  # the rest are pairs of different ids
        if right[e] or found[g] or not errors[e, g] < fraction * models[estimates[e][0]].diameter:
            continue
        right[e] = found[g] = True
        matched_error[e] = errors[e, g]
    return Verdicts(tuple(right), tuple(found), tuple(float(x) for x in matched_error))


def crop_box(
    mask: np.ndarray, points: np.ndarray, margin: float = 0.15, min_fraction: float = 0.3
) -> tuple[int, int, int, int]:
    """``(top, left, height, width)`` of the region of a view worth showing: the bounding box of ``mask (H, W)``
    (bool) and of ``points (N, 2)`` (x, y pixels; those outside the image are left out), grown by ``margin`` of its
    longer side on each side, then to the image's aspect ratio and at least ``min_fraction`` of its size, moved
    inside the image. The whole image where there is nothing to show."""
    H, W = mask.shape
    rows, cols = np.nonzero(mask)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    pts = pts[np.isfinite(pts).all(1) & (pts[:, 0] >= 0) & (pts[:, 0] < W) & (pts[:, 1] >= 0) & (pts[:, 1] < H)]
    ys = np.concatenate([rows.astype(np.float64), pts[:, 1]])
    xs = np.concatenate([cols.astype(np.float64), pts[:, 0]])
    if len(ys) == 0:
        return 0, 0, H, W
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    grow = margin * max(y1 - y0, x1 - x0)
    h, w = y1 - y0 + 2 * grow, x1 - x0 + 2 * grow
    h, w = max(h, w * H / W, min_fraction * H), max(w, h * W / H, min_fraction * W)  # the image's aspect ratio
    h, w = min(H, int(np.ceil(h))), min(W, int(np.ceil(w)))
    top = int(np.clip(round((y0 + y1 - h) / 2), 0, H - h))
    left = int(np.clip(round((x0 + x1 - w) / 2), 0, W - w))
    return top, left, h, w


def scene_figure(
    output,
    scene: Scene,
    models: Mapping[int, ObjectModel],
    meshes,
    path: Path,
    judge_models: Mapping[int, ObjectModel] | None = None,
) -> Path:
    """Write the figure of one scene's :class:`bop_cender.method.SceneOutput` to ``path`` (PNG, atomically).

    ``models`` and ``meshes``: the method's (centres, outlines); ``judge_models``: those the verdicts are judged on,
    the scorer's evaluation models where the dataset has its own (default: ``models``)."""
    plt = pyplot()

    views = scene.views
    V = len(views)
    H, W = views[0].height, views[0].width
    center = output.heatmaps.center.detach().cpu().amax(1).numpy()
    curv = output.heatmaps.curvature.detach().cpu().numpy()
    est = [(o.obj_id, o.T_world_model) for o in output.estimate.objects]
    gt = [(g.obj_id, g.T_world_model) for g in scene.gt if models[g.obj_id].is_target]
    verdicts = judge_estimates(est, gt, judge_models or models) if gt else None
    est_inst = _instances(est, scene, meshes, H, W)
    gt_inst = _instances(gt, scene, meshes, H, W)
    Ks, T_cw = np.stack([v.K for v in views]), np.stack([v.T_cam_world for v in views])
    detected = _projected([c.position for c in output.centers], Ks, T_cw)  # (V, N, 2)
    gt_centres = _projected([T[:3, :3] @ models[obj_id].center + T[:3, 3] for obj_id, T in gt], Ks, T_cw)
    fig, axes = plt.subplots(4, V, figsize=(2.2 * V, 2.2 * 4 * H / W + 0.6), squeeze=False)
    for v, view in enumerate(views):
        detected_xy, gt_xy = detected[v], gt_centres[v]
        mask = (est_inst[v] >= 0) | (gt_inst[v] >= 0)
        top, left, h, w = crop_box(mask, np.concatenate([detected_xy, gt_xy]))
        window = (slice(top, top + h), slice(left, left + w))
        rgb = read_rgb(view, H, W)
        axes[0, v].imshow(rgb[window])
        axes[0, v].set_title(f"image {view.im_id}", fontsize=7)
        axes[1, v].imshow(center[v][window], cmap="magma", vmin=0, vmax=1)
        for xy, marker, colour, size, width in ((detected_xy, "x", "red", 5, 1.2), (gt_xy, "o", "lime", 6, 0.8)):
            x, y = xy[:, 0] - 0.5 - left, xy[:, 1] - 0.5 - top  # pixel centres at u + 0.5 (project_points)
            axes[1, v].plot(x, y, marker, ls="none", mfc="none", color=colour, ms=size, mew=width)
        axes[1, v].set_xlim(-0.5, w - 0.5)
        axes[1, v].set_ylim(h - 0.5, -0.5)
        axes[2, v].imshow(curv[v][window], cmap="gray", vmin=0, vmax=1)
        overlay = rgb.astype(np.float32) / 255.0
        if verdicts is not None:
            for k, found in enumerate(verdicts.gt_found):
                if not found:
                    overlay[outline(gt_inst[v] == k)] = MISSED
        for k in range(len(est)):
            colour = UNJUDGED if verdicts is None else (RIGHT if verdicts.estimate_right[k] else WRONG)
            overlay[outline(est_inst[v] == k)] = colour
        axes[3, v].imshow(overlay[window])
    pose_label = "poses (yellow)" if verdicts is None else "poses: right (green) /\nwrong (red) / missed GT (cyan)"
    for ax, label in zip(axes[:, 0], ("input", "centers", "curvature", pose_label), strict=True):
        ax.set_ylabel(label, fontsize=7)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    judged = ""
    if verdicts is not None:
        judged = f", {sum(verdicts.estimate_right)} right (MSSD < {MSSD_FRACTION:.0%} of the diameter)"
    title = f"scene {scene.key}: {len(est)} estimated, {len(gt)} GT{judged}"
    fig.suptitle(figure_title(title, output.estimate.timings, fig.get_figwidth()), fontsize=8)
    return save_png(fig, path, dpi=110)


def figure_title(head: str, timings: Mapping[str, float], width_in: float) -> str:
    """``head`` and the stages' times, wrapped to a figure ``width_in`` inches wide (:data:`TITLE_CHARS_PER_INCH`;
    a figure of one or two views cut its one-line title at both sides); a time and its unit stay on one line."""
    times = ", ".join(f"{k}\u00a0{v:.1f}\u00a0s" for k, v in timings.items())
    return textwrap.fill(f"{head}; {times}", width=max(20, int(TITLE_CHARS_PER_INCH * width_in)))


def _projected(points: Sequence[np.ndarray], Ks: np.ndarray, T_cam_world: np.ndarray) -> np.ndarray:
    """``(V, N, 2)`` continuous image points of world ``points`` in each view
    (:func:`~bop_cender.geometry.camera.project_points`), NaN behind a camera (neither drawn nor counted in the crop)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    cam = transform_points(T_cam_world, points)  # (V, N, 3)
    xy = np.stack([project_points(K, p) for K, p in zip(Ks, cam, strict=True)])
    return np.where(cam[..., 2:3] > 1e-6, xy, np.nan)


def _instances(objects, scene: Scene, meshes, H: int, W: int) -> np.ndarray:
    """``(V, H, W)`` int64: the index into ``objects`` of the object seen at each pixel (the objects hide each
    other), -1 where none."""
    if not objects:
        return np.full((len(scene.views), H, W), -1, dtype=np.int64)
    mesh_list: list[RenderMesh] = [meshes(obj_id) for obj_id, _ in objects]
    T = np.stack([[v.T_cam_world @ T_wm for _, T_wm in objects] for v in scene.views])
    Ks = np.stack([v.K for v in scene.views])
    return render_scene(mesh_list, torch.as_tensor(T, dtype=torch.float32), Ks, H, W).instance.numpy()


def outline(mask: np.ndarray) -> np.ndarray:
    """``(H, W)`` bool: the pixels of ``mask`` with a 4-neighbour outside it (or on the image's border)."""
    inner = np.zeros_like(mask)
    inner[1:-1, 1:-1] = mask[1:-1, 1:-1] & mask[:-2, 1:-1] & mask[2:, 1:-1] & mask[1:-1, :-2] & mask[1:-1, 2:]
    return mask & ~inner


def read_rgb(view, H: int, W: int) -> np.ndarray:
    """The view's image as the method saw it (:func:`~bop_cender.data.canvas.read_view_rgb`); black where unreadable."""
    from bop_cender.data.canvas import read_view_rgb
    from bop_cender.errors import BopCenderError

    if view.rgb_path is None or not Path(view.rgb_path).is_file():
        return np.zeros((H, W, 3), np.uint8)
    try:
        return read_view_rgb(view)
    except BopCenderError:
        return np.zeros((H, W, 3), np.uint8)
