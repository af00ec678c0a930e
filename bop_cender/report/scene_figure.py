"""Per-scene figure of a run (``bop-cender run --vis DIR``): what each stage saw and produced.

Columns are views; rows are the input image, the center heatmap with the detected 3D centres
projected (red crosses; GT centres as green circles), the curvature heatmap, and the input with the
contours of the estimated models (red) and of the GT models (green) where the scene is annotated.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from bop_cender.data.bop_io import atomic_path
from bop_cender.data.types import Scene
from bop_cender.render.mesh import RenderMesh
from bop_cender.render.rasterizer import render_scene


def scene_figure(output, scene: Scene, models, meshes, path: Path) -> Path:
    """Write the figure of one scene's :class:`bop_cender.method.SceneOutput` to ``path`` (PNG, atomically)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    views = scene.views
    V = len(views)
    H, W = views[0].height, views[0].width
    center = output.heatmaps.center.detach().cpu().amax(1).numpy()
    curv = output.heatmaps.curvature.detach().cpu().numpy()
    est = [(o.obj_id, o.T_world_model) for o in output.estimate.objects]
    gt = [(g.obj_id, g.T_world_model) for g in scene.gt if models[g.obj_id].is_target]
    est_edges = _contours(est, scene, meshes, H, W)
    gt_edges = _contours(gt, scene, meshes, H, W)
    fig, axes = plt.subplots(4, V, figsize=(2.2 * V, 2.2 * 4 * H / W + 0.6), squeeze=False)
    for v, view in enumerate(views):
        rgb = _read_rgb(view.rgb_path, H, W)
        axes[0, v].imshow(rgb)
        axes[0, v].set_title(f"image {view.im_id}", fontsize=7)
        axes[1, v].imshow(center[v], cmap="magma", vmin=0, vmax=1)
        for c in output.centers:
            x, y = _project(view, c.position)
            axes[1, v].plot(x - 0.5, y - 0.5, "x", color="red", ms=5, mew=1.2)
        for obj_id, T in gt:
            x, y = _project(view, T[:3, :3] @ models[obj_id].center + T[:3, 3])
            axes[1, v].plot(x - 0.5, y - 0.5, "o", mfc="none", color="lime", ms=6, mew=0.8)
        axes[2, v].imshow(curv[v], cmap="gray", vmin=0, vmax=1)
        overlay = rgb.astype(np.float32) / 255.0
        if gt_edges is not None:
            overlay[gt_edges[v]] = (0.1, 1.0, 0.1)
        if est_edges is not None:
            overlay[est_edges[v]] = (1.0, 0.1, 0.1)
        axes[3, v].imshow(overlay)
    for ax, label in zip(axes[:, 0], ("input", "centers", "curvature", "poses (red) / GT (green)"), strict=True):
        ax.set_ylabel(label, fontsize=7)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    t = output.estimate.timings
    fig.suptitle(f"scene {scene.key}: {len(est)} estimated, {len(gt)} GT; " +
                 ", ".join(f"{k} {v:.1f} s" for k, v in t.items()), fontsize=8)  # fmt: skip
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)
    return path


def _project(view, point: np.ndarray) -> tuple[float, float]:
    p = view.T_cam_world[:3, :3] @ point + view.T_cam_world[:3, 3]
    x, y = (view.K @ p)[:2] / max(p[2], 1e-6)
    return float(x), float(y)


def _contours(objects, scene: Scene, meshes, H: int, W: int) -> np.ndarray | None:
    """``(V, H, W)`` bool outlines of each object's visible region, or None with no objects."""
    if not objects:
        return None
    mesh_list: list[RenderMesh] = [meshes(obj_id) for obj_id, _ in objects]
    T = np.stack([[v.T_cam_world @ T_wm for _, T_wm in objects] for v in scene.views])
    Ks = np.stack([v.K for v in scene.views])
    inst = render_scene(mesh_list, torch.as_tensor(T, dtype=torch.float32), Ks, H, W).instance
    edge = torch.zeros_like(inst, dtype=torch.bool)
    edge[:, 1:] |= inst[:, 1:] != inst[:, :-1]
    edge[:, :, 1:] |= inst[:, :, 1:] != inst[:, :, :-1]
    return edge.numpy()


def _read_rgb(path: Path | None, H: int, W: int) -> np.ndarray:
    if path is None or not Path(path).is_file():
        return np.zeros((H, W, 3), np.uint8)
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        return np.zeros((H, W, 3), np.uint8)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
