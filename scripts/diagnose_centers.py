"""Where a network's 2D centre peaks fail, on a DIMO-layout split with ground truth.

``bop-cender heatmaps`` counts a centre peak as found when stage 2's detector puts one within 5 px of the GT
centre's projection. This script says why the rest is not: per view, every target part at least 10 % visible
(BOP's rule, the pile rendered together) against the peaks of the predicted centre map, and prints

1. the share found within 5 px by the part's visible fraction and by object id;
2. how far the nearest peak of any height (>= 0.05) lies: within 3 / 5 / 8 / 12 / 20 px (a detection that is
   there but misplaced, against a part the network does not see at all);
3. the predicted map's value at the GT centres (quantiles: peaks too low for stage 2's threshold);
4. detector variants on the same maps: stage 2's threshold, ``peak_local_max``'s ``min_distance`` and a
   Gaussian pre-smoothing of the map (whether post-processing alone could find what the 5 px figure misses).

    python scripts/diagnose_centers.py --data-root DATA/dimo_test --split sim [--weights W] [--scenes K]
"""

from __future__ import annotations

import argparse
import itertools
import sys

import numpy as np
import torch
from scipy.ndimage import gaussian_filter

from bop_cender.centers import CenterConfig, find_peaks
from bop_cender.data.registry import DatasetRequest
from bop_cender.datasets import open_with_demo
from bop_cender.errors import BopCenderError
from bop_cender.meshes import MeshCache
from bop_cender.net.metrics import match_peaks
from bop_cender.net.predictor import NetPredictor
from bop_cender.net.weights import load_weights, shipped_weights_path
from bop_cender.visibility import pile_visibility

TOLERANCE_PX = 5.0
MIN_VISIB = 0.1
VISIB_BINS = (0.1, 0.25, 0.5, 0.75, 1.0)


def gt_centres(scene, models) -> list[np.ndarray]:
    """Per view, ``(n, 4)``: x, y (px), visible fraction and obj_id of every target part of the scene."""
    gt = [g for g in scene.gt if g.obj_id in models]
    T_cw = np.stack([v.T_cam_world for v in scene.views])
    T_cm = np.einsum("vij,mjk->vmik", T_cw, np.stack([g.T_world_model for g in gt]))
    K = np.stack([v.K for v in scene.views])
    meshes = MeshCache(models)
    fract = pile_visibility([meshes(g.obj_id) for g in gt], T_cm, K, scene.views[0].height, scene.views[0].width).fract
    out = []
    for i, view in enumerate(scene.views):
        rows = []
        for m, g in enumerate(gt):
            model = models[g.obj_id]
            if not model.is_target:
                continue
            p = T_cm[i, m, :3, :3] @ model.center + T_cm[i, m, :3, 3]
            x, y = (view.K @ p)[:2] / p[2]
            rows.append((x, y, float(fract[i, m]), g.obj_id))
        out.append(np.array(rows, dtype=np.float64).reshape(-1, 4))
    return out


def counts(records, sigma: float, threshold: float, min_distance: int) -> tuple[int, int, int]:
    """TP, FP, FN of the detector variant over every view (GT: the parts at least ``MIN_VISIB`` visible)."""
    tp = fp = fn = 0
    for pts, cmap in records:
        xy = find_peaks(gaussian_filter(cmap, sigma) if sigma > 0 else cmap, threshold, min_distance)[0]
        g = pts[pts[:, 2] > MIN_VISIB, :2]
        k = match_peaks(xy, g, TOLERANCE_PX)
        tp, fp, fn = tp + k, fp + len(xy) - k, fn + len(g) - k
    return tp, fp, fn


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data-root", default=None, help="DIMO-layout dataset (default: the embedded demo)")
    ap.add_argument("--split", default="sim")
    ap.add_argument("--weights", default=None, help="weights file (default: the shipped DIMO network)")
    ap.add_argument("--scenes", type=int, default=None, help="only the first K scenes")
    args = ap.parse_args()
    torch.set_num_threads(max(1, torch.get_num_threads()))
    try:
        ds = open_with_demo(DatasetRequest("dimo", args.data_root, args.split))
        weights = load_weights(args.weights or shipped_weights_path("dimo"), dataset="dimo")
    except BopCenderError as e:
        sys.exit(f"error: {e.format()}")
    predictor = NetPredictor(weights)
    stage2 = CenterConfig()
    records = []
    for key in ds.scene_keys[: args.scenes]:
        scene = ds.scene(key)
        maps = predictor.predict(scene).center[:, 0].cpu().numpy()  # (V, H, W): DIMO's one shared channel
        records += list(zip(gt_centres(scene, ds.models), maps, strict=True))
    print(f"{len(records)} views of dimo {args.split}; GT: target parts > {MIN_VISIB:.0%} visible; stage 2's "
          f"detector: threshold {stage2.peak_threshold}, min_distance {stage2.peak_min_distance}")  # fmt: skip
    found_by_bin, total_by_bin = np.zeros(4, int), np.zeros(4, int)
    found_by_obj: dict[int, list[int]] = {}
    nearest, value_at = [], []
    for pts, cmap in records:
        peaks = find_peaks(cmap, stage2.peak_threshold, stage2.peak_min_distance)[0]
        low = find_peaks(cmap, 0.05, stage2.peak_min_distance)[0]
        H, W = cmap.shape
        for x, y, visib, obj in pts:
            if visib <= MIN_VISIB:
                continue
            found = bool(len(peaks)) and float(np.hypot(*(peaks - (x, y)).T).min()) <= TOLERANCE_PX
            b = int(np.searchsorted(VISIB_BINS, visib, side="right") - 1)
            b = min(max(b, 0), 3)
            found_by_bin[b] += found
            total_by_bin[b] += 1
            found_by_obj.setdefault(int(obj), [0, 0])
            found_by_obj[int(obj)][0] += found
            found_by_obj[int(obj)][1] += 1
            nearest.append(float(np.hypot(*(low - (x, y)).T).min()) if len(low) else np.inf)
            value_at.append(float(cmap[int(np.clip(y, 0, H - 1)), int(np.clip(x, 0, W - 1))]))
    print(f"\n1. found within {TOLERANCE_PX:g} px, by visible fraction and by object")
    for b in range(4):
        share = found_by_bin[b] / max(1, total_by_bin[b])
        print(
            f"   visible [{VISIB_BINS[b]:.2f}, {VISIB_BINS[b + 1]:.2f}): {found_by_bin[b]}/{total_by_bin[b]} ({share:.2f})"
        )
    for obj, (f, n) in sorted(found_by_obj.items()):
        print(f"   object {obj}: {f}/{n} ({f / n:.2f})")
    nearest_arr = np.array(nearest)
    print("\n2. nearest peak of any height (>= 0.05): " + ", ".join(
        f"within {t} px {np.mean(nearest_arr <= t):.2f}" for t in (3, 5, 8, 12, 20)))  # fmt: skip
    q = np.quantile(value_at, [0.1, 0.25, 0.5, 0.75, 0.9]) if value_at else np.full(5, np.nan)
    print("3. predicted value at the GT centres, quantiles 10/25/50/75/90 %: " + " / ".join(f"{v:.2f}" for v in q))
    print("\n4. detector variants (pre-smoothing sigma px, threshold, min_distance): TP FP FN, F1")
    for sigma, threshold, min_distance in itertools.product((0, 1, 2), (0.1, 0.15, 0.2, 0.3), (2, 5, 8)):
        tp, fp, fn = counts(records, sigma, threshold, min_distance)
        f1 = 2 * tp / max(1, 2 * tp + fp + fn)
        print(f"   sigma {sigma} threshold {threshold:.2f} min_distance {min_distance}: {tp} {fp} {fn}, F1 {f1:.3f}")


if __name__ == "__main__":
    main()
