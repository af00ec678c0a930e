"""Stage 1 alone (``bop-cender heatmaps``): a predictor over a split, its figures against the GT, PNGs on request.

For every scene: the predictor's heatmaps (network or oracle), the per-view inference time, and where the
split has ground truth the GT heatmaps (:func:`bop_cender.net.targets.scene_targets`) scored with the
validation figures of training (:class:`bop_cender.net.metrics.HeatmapMetrics`): center-peak precision,
recall and F1 at a pixel tolerance, curvature AP and F1 at t_b. A PNG per view puts side by side the
input, the predicted center and curvature, and the GT center and curvature.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bop_cender.data.bop_io import write_image
from bop_cender.data.canvas import read_view_rgb
from bop_cender.data.types import Dataset
from bop_cender.net.heatmaps import Heatmaps
from bop_cender.net.metrics import HeatmapMetrics, HeatmapMetricsConfig
from bop_cender.net.targets import TargetConfig, scene_targets
from bop_cender.progress import progress_bar
from bop_cender.render.mesh import RenderMesh


@dataclass
class HeatmapReport:
    """What ``heatmaps`` measured.

    Attributes:
        dataset, split: the data.
        source: ``oracle`` or the weights file.
        scenes, views: how many were predicted.
        seconds_per_view: mean inference time per view (the predictor's own time, image reading excluded).
        metrics: :meth:`HeatmapMetrics.result` over every view with GT; empty without GT.
        pngs: the PNGs written.
    """

    dataset: str
    split: str
    source: str
    scenes: int = 0
    views: int = 0
    seconds_per_view: float = 0.0
    metrics: dict[str, float] = field(default_factory=dict)
    pngs: list[Path] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return {
            "dataset": self.dataset,
            "split": self.split,
            "source": self.source,
            "scenes": self.scenes,
            "views": self.views,
            "ms_per_view": round(1000 * self.seconds_per_view, 3),
            "metrics": self.metrics,
            "pngs": [path.name for path in self.pngs],  # what a later run into the same folder replaces
        }


def evaluate_heatmaps(
    dataset: Dataset,
    predictor,
    targets: TargetConfig,
    meshes: Callable[[int], RenderMesh],
    source: str,
    scene_keys: Sequence[str] | None = None,
    png_dir: Path | None = None,
    metrics_config: HeatmapMetricsConfig | None = None,
    progress: bool = True,
) -> HeatmapReport:
    """Run ``predictor.predict(scene) -> Heatmaps`` over the scenes; score against the GT heatmaps where there is GT.

    The time per view is the predictor's ``last_seconds_per_view`` where it has one (the network: inference
    alone, image reading excluded), else the time of ``predict``."""
    keys = list(dataset.scene_keys if scene_keys is None else scene_keys)
    report = HeatmapReport(dataset.name, dataset.split, source)
    metrics = HeatmapMetrics(metrics_config or HeatmapMetricsConfig())
    seconds = 0.0
    for key in progress_bar(keys, desc=f"heatmaps {dataset.name} {dataset.split}", unit="scene", disable=not progress):
        scene = dataset.loader(key)
        t0 = time.perf_counter()
        pred: Heatmaps = predictor.predict(scene)
        own = getattr(predictor, "last_seconds_per_view", None)
        seconds += own * pred.num_views if own is not None else time.perf_counter() - t0
        report.scenes += 1
        report.views += pred.num_views
        gt = None
        if scene.gt:
            gt = scene_targets(scene, dataset.models, meshes, targets, pred.channel_obj_ids, pred.center.device)
            metrics.update_heatmaps(pred, gt)
        if png_dir is not None:
            report.pngs.extend(_write_pngs(png_dir, scene, pred, gt))
    report.seconds_per_view = seconds / max(1, report.views)
    if metrics.n_views:
        report.metrics = {k: float(v) for k, v in metrics.result().items()}
    return report


def side_by_side(image: np.ndarray, pred: Heatmaps, gt: Heatmaps | None, v: int) -> np.ndarray:
    """One view as ``(H, k*W, 3)`` uint8: input, predicted center (max over channels) and curvature, then the GT's."""
    panels = [image]
    for maps in (pred, gt):
        if maps is None:
            continue
        for m in (maps.center[v].amax(dim=0), maps.curvature[v]):
            grey = (m.detach().float().cpu().clamp(0, 1).numpy() * 255).round().astype(np.uint8)
            panels.append(np.repeat(grey[..., None], 3, axis=2))
    gap = np.full((image.shape[0], 4, 3), 255, np.uint8)
    out = [panels[0]]
    for p in panels[1:]:
        out += [gap, p]
    return np.concatenate(out, axis=1)


def _write_pngs(folder: Path, scene, pred: Heatmaps, gt: Heatmaps | None) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for v, view in enumerate(scene.views):
        image = read_view_rgb(view) if view.rgb_path is not None else np.zeros((view.height, view.width, 3), np.uint8)
        path = folder / f"{scene.key.replace('/', '_')}_{view.im_id:06d}.png"
        write_image(path, side_by_side(image, pred, gt, v))
        written.append(path)
    return written


def format_report(report: HeatmapReport) -> str:
    """The figures as a small table."""
    lines = [
        f"heatmaps of {report.dataset} {report.split} ({report.scenes} scenes, {report.views} views) from {report.source}"
    ]
    lines.append(f"  inference: {1000 * report.seconds_per_view:.1f} ms per view")
    m = report.metrics
    if not m:
        lines.append("  no ground truth: no figures")
        return "\n".join(lines)
    lines.append("  figure              value")
    for name in ("center_precision", "center_recall", "center_f1", "curvature_ap", "curvature_f1"):
        lines.append(f"  {name:<18}  {m[name]:.3f}")
    if "curvature_best_threshold" in m:
        lines.append(
            f"  curvature F1 is best ({m['curvature_best_f1']:.3f}) binarised at {m['curvature_best_threshold']:.3f}"
        )
    lines.append(f"  center peaks: {int(m['center_tp'])} TP, {int(m['center_fp'])} FP, {int(m['center_fn'])} FN")
    return "\n".join(lines)
