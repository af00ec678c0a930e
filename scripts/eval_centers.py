"""Stage 2 alone on oracle heatmaps: how many GT centres the 3D centres find, and the false ones.

For each scene of a DIMO-layout split, the oracle center heatmaps (rendered from the GT) go through
:func:`bop_cender.centers.detect_centers` with the known object count; a GT centre counts as found
when a detected centre lies within 5 mm of it, a detected centre is false when it lies 5 mm or more
from every GT centre. Per setting: found / total, false centres, median error of the found ones, and
per-image targets found (an image's targets: objects with ``visib_fract >= 0.1`` in it, BOP's rule;
one counts as found when its GT centre is). With ``--misses``, each missed GT centre of the first
setting, with the number of views where the heatmap has a peak on it (within 1 px of its projection:
fewer than two, and no triangulation can find it) and the nearest detected centre:

    python scripts/eval_centers.py --data-root DATA --split sim --misses
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace

import numpy as np

from bop_cender.centers import CenterConfig, detect_centers, find_peaks, project_points
from bop_cender.data.registry import DatasetRequest
from bop_cender.datasets import open_with_demo
from bop_cender.errors import BopCenderError
from bop_cender.meshes import MeshCache
from bop_cender.method import CenDerNetConfig
from bop_cender.net.oracle import OraclePredictor
from bop_cender.net.predictor import NetPredictor
from bop_cender.net.weights import load_weights, shipped_weights_path
from bop_cender.visibility import pile_visibility

SETTINGS = {
    "ours": CenterConfig(),
    "paper d_c 30, d_o 30": CenterConfig.paper(),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data-root", default=None)
    ap.add_argument("--split", default="sim")
    ap.add_argument("--scenes", type=int, default=None)
    ap.add_argument("--misses", action="store_true", help="print each miss and false centre of the first setting")
    ap.add_argument("--weights", default=None, help="a network's weights file, or 'shipped' (default: the oracle)")
    ap.add_argument("--test-flips", type=int, choices=(1, 2, 4), default=1, help="the network's test flips (default 1)")
    ap.add_argument("--setting", action="append", default=[], metavar="KEY=V[,KEY=V]",
                    help="a CenterConfig to compare (our defaults but these fields), e.g. peak_threshold=0.1,"
                    "min_view_score=0.1; repeatable (default: ours and the paper's)")  # fmt: skip
    args = ap.parse_args()
    try:
        settings = {text: _setting(text) for text in args.setting} or SETTINGS
    except (ValueError, BopCenderError) as e:
        ap.error(f"--setting: {e}")
    ds = open_with_demo(DatasetRequest("dimo", args.data_root, args.split))  # no data root: the demo, silently
    config = CenDerNetConfig.for_dataset("dimo")
    meshes = MeshCache(ds.models)
    if args.weights is None:
        predictor = OraclePredictor(ds.models, meshes, config.targets)
    else:
        path = shipped_weights_path("dimo") if args.weights == "shipped" else args.weights
        predictor = NetPredictor(load_weights(path, dataset="dimo"), flips=args.test_flips)
    found = dict.fromkeys(settings, 0)
    false = dict.fromkeys(settings, 0)
    image_targets_found = dict.fromkeys(settings, 0)
    errors: dict[str, list[float]] = {k: [] for k in settings}
    total = image_targets = 0
    for key in ds.scene_keys[: args.scenes]:
        scene = ds.scene(key)
        maps = predictor.predict(scene).center.numpy()
        Ks = np.stack([v.K for v in scene.views])
        T_cw = np.stack([v.T_cam_world for v in scene.views])
        gts = [g for g in scene.gt if g.obj_id in ds.models]
        targets = [i for i, g in enumerate(gts) if ds.models[g.obj_id].is_target]
        gt = np.array([gts[i].T_world_model[:3, :3] @ ds.models[gts[i].obj_id].center + gts[i].T_world_model[:3, 3]
                       for i in targets]).reshape(-1, 3)  # fmt: skip
        total += len(gt)
        if not len(gt):
            continue
        T_cm = np.einsum("vij,mjk->vmik", T_cw, np.stack([g.T_world_model for g in gts]))
        H, W = scene.views[0].height, scene.views[0].width
        fract = pile_visibility(meshes.many([g.obj_id for g in gts]), T_cm, Ks, H, W).fract[:, targets]  # (V, M)
        per_image = (fract >= 0.1).sum(0)  # (M,) images where each GT centre is a target
        image_targets += int(per_image.sum())
        for s, (name, setting) in enumerate(settings.items()):
            centers = detect_centers(maps, Ks, T_cw, setting, None, {0: len(gt)})
            P = np.array([c.position for c in centers]).reshape(-1, 3)
            dist = np.linalg.norm(gt[:, None] - P[None], axis=-1) if len(P) else np.full((len(gt), 1), np.inf)
            nearest = dist.min(1)
            found[name] += int((nearest < 5.0).sum())
            false[name] += int((dist.min(0) >= 5.0).sum()) if len(P) else 0
            image_targets_found[name] += int(per_image[nearest < 5.0].sum())
            errors[name] += nearest[nearest < 5.0].tolist()
            if args.misses and s == 0:
                _print_misses(key, maps[:, 0], Ks, T_cw, gt, nearest, dist, centers, setting, per_image)
    print(f"{len(ds.scene_keys[: args.scenes])} scenes, {total} GT centres, {image_targets} per-image targets"
          f" ({ds.root}, split {args.split})")  # fmt: skip
    for name in settings:
        med = np.median(errors[name]) if errors[name] else float("nan")
        print(
            f"{name}: {found[name]}/{total} found within 5 mm ({found[name] / max(total, 1):.3f}), "
            f"{false[name]} false; median error {med:.2f} mm; per-image targets "
            f"{image_targets_found[name]}/{image_targets} ({image_targets_found[name] / max(image_targets, 1):.3f})"
        )


def _setting(text: str) -> CenterConfig:
    """``KEY=V[,KEY=V]`` as our :class:`CenterConfig` with those fields changed (ValueError names what is wrong)."""
    defaults = CenterConfig()
    changes = {}
    for item in text.split(","):
        key, sep, value = item.partition("=")
        if not sep or not hasattr(defaults, key):
            raise ValueError(f"{item!r} is not FIELD=VALUE of a CenterConfig field")
        changes[key] = type(getattr(defaults, key))(value)
    return replace(defaults, **changes)


def _print_misses(key, maps, Ks, T_cw, gt, nearest, dist, centers, setting, per_image) -> None:
    xy, front = project_points(gt, Ks, T_cw)  # (V, M, 2)
    peaks = [find_peaks(m, setting.peak_threshold, setting.peak_min_distance)[0] for m in maps]
    on_peak = np.zeros((len(maps), len(gt)), dtype=bool)
    for v, p in enumerate(peaks):
        if len(p):
            on_peak[v] = front[v] & (np.linalg.norm(xy[v][:, None] - p[None], axis=-1).min(1) <= 1.0)
    for i in np.flatnonzero(nearest >= 5.0):
        print(f"  {key} miss GT {i}: peaks on it in {on_peak[:, i].sum()} of {len(maps)} views, "
              f"target in {per_image[i]} images; nearest centre {nearest[i]:.1f} mm")  # fmt: skip
    for j in np.flatnonzero(dist.min(0) >= 5.0) if len(centers) else []:
        print(f"  {key} false centre {j}: score {centers[j].score:.2f}, {dist[:, j].min():.1f} mm from a GT centre")


if __name__ == "__main__":
    try:
        main()
    except BopCenderError as e:
        sys.exit(f"error: {e}")
