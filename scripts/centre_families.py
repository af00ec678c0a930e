"""Which parts a network's centre map finds, per part family: the figure that showed T-LESS's brackets lost.

Per view, every target instance more visible than ``--min-visib`` (0.5, the T-LESS targets' rule) is looked up in
the network's class-agnostic center map (stage 2's join of its channels, ``centers.class_agnostic_map``: one for DIMO,
one per object id for T-LESS) at the
projection of its 3D centre (bounding-box centre): the map's highest value within 3 px of it, whether stage 2's peak
detector (its threshold and minimum distance, ``CenterConfig``) has a peak within ``--peak-px`` (5) of it, and the
distance to the nearest peak. Printed per part family (our synthetic catalogues name each object's part type: a
bracket, a flange...; other data per object id):

    python scripts/centre_families.py --dataset tless --data-root DATA/tless_test --split test [--weights W]

Measured (twentieth session, the shipped T-LESS network, test set 7272): brackets 109 instances, median map 0.05,
a peak within 5 px for 3 %; flanges 0.98 / 77 %, slotted plates 0.90 / 97 %: a bracket's centre lies in the air
inside the L, where the center head finds nothing to fire on (``bop_cender/net/votes.py``). ``--weights oracle``
reads the GT's own maps (every instance found: the check of this script).
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bop_cender.centers import CenterConfig, class_agnostic_map, find_peaks, project_points
from bop_cender.errors import BopCenderError
from bop_cender.geometry.poses import transform_points
from bop_cender.runner import RunRequest, method_for
from bop_cender.visibility import pile_visibility


@dataclass(frozen=True)
class CentreLookup:
    """One target instance in one view: its family, the map's value at its centre, the nearest peak (px; inf: none)."""

    family: str
    value: float
    nearest_peak_px: float


def family_names(root: Path, models: Mapping[int, object]) -> dict[int, str]:
    """Object id -> part family for a set written by ``bop-cender synth`` (its record names the layout and the
    catalogue); ``obj N`` for any other dataset."""
    import json

    from bop_cender.synth.record import RECORD_FILE

    names = {obj_id: f"obj {obj_id}" for obj_id in models}
    record = Path(root) / RECORD_FILE
    if not record.is_file():
        return names
    try:
        info = json.loads(record.read_text())
        if info.get("layout") == "dimo":
            from bop_cender.synth.write_dimo import dimo_models

            parts = dimo_models(int(info["catalogue_seed"]))
        elif info.get("layout") == "tless":
            from bop_cender.synth.write_tless import tless_models

            parts = tless_models(int(info["catalogue_seed"]))
        else:
            return names
    except (OSError, ValueError, KeyError, TypeError):
        return names
    names.update({obj_id: part.name for obj_id, part in parts.items() if obj_id in models})
    return names


def view_lookups(
    agnostic: np.ndarray, centres_xy: np.ndarray, families: Sequence[str], config: CenterConfig, window: int = 3
) -> list[CentreLookup]:
    """Lookups of the instances ``centres_xy (M, 2)`` (continuous image coordinates) in one view's class-agnostic
    map ``agnostic (H, W)``; instances whose centre projects outside the view are left out."""
    H, W = agnostic.shape
    peaks = find_peaks(agnostic, config.peak_threshold, config.peak_min_distance)[0].reshape(-1, 2)
    out = []
    for (x, y), family in zip(centres_xy, families, strict=True):
        u, v = int(math.floor(x)), int(math.floor(y))
        if not (0 <= u < W and 0 <= v < H):
            continue
        value = float(agnostic[max(0, v - window) : v + window + 1, max(0, u - window) : u + window + 1].max())
        nearest = float(np.hypot(peaks[:, 0] - x, peaks[:, 1] - y).min()) if len(peaks) else math.inf
        out.append(CentreLookup(family, value, nearest))
    return out


def family_table(lookups: Sequence[CentreLookup], peak_px: float) -> list[str]:
    """Markdown lines: per family, instances, the median map value at their centres, the share with a peak within
    ``peak_px`` and the nearest peak's quartiles (px)."""
    lines = [
        f"| family | instances | median map at centre | peak within {peak_px:g} px | nearest peak px (25/50/75 %) |",
        "|---|---:|---:|---:|---|",
    ]
    for family in sorted({lk.family for lk in lookups}):
        mine = [lk for lk in lookups if lk.family == family]
        values = np.array([lk.value for lk in mine])
        nearest = np.array([lk.nearest_peak_px for lk in mine])
        q = np.percentile(nearest, [25, 50, 75], method="nearest")  # no interpolation between inf and inf
        quartiles = "/".join("none" if not math.isfinite(x) else f"{x:.0f}" for x in q)
        share = float(np.mean(nearest <= peak_px))
        lines.append(f"| {family} | {len(mine)} | {np.median(values):.2f} | {share:.2f} | {quartiles} |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", choices=("dimo", "tless", "bop"), default="dimo", help="layout (default dimo)")
    ap.add_argument("--data-root", default=None, help="dataset root (default: the embedded demo)")
    ap.add_argument("--split", default=None, help="split (default: dimo sim, tless/bop test)")
    ap.add_argument("--weights", default=None, help="network weights, or 'oracle' (default: the shipped network)")
    ap.add_argument("--scenes", type=int, default=None, help="only the first K scenes")
    ap.add_argument("--min-visib", type=float, default=0.5, help="instances more visible than this (default 0.5)")
    ap.add_argument("--peak-px", type=float, default=5.0, help="a peak this close finds the centre (default 5)")
    args = ap.parse_args()
    if args.scenes is not None and args.scenes < 1:
        ap.error(f"--scenes must be at least 1, got {args.scenes}")
    if not 0.0 <= args.min_visib < 1.0:
        ap.error(f"--min-visib must be in [0, 1), got {args.min_visib}")
    if not args.peak_px > 0:
        ap.error(f"--peak-px must be above 0, got {args.peak_px}")
    split = args.split or ("sim" if args.dataset == "dimo" else "test")
    oracle = args.weights == "oracle"
    try:
        request = RunRequest(args.dataset, args.data_root, split, Path("unused.csv"),
                             heatmaps="oracle" if oracle else "net", weights=None if oracle else args.weights)  # fmt: skip
        request, dataset, method = method_for(request)
        names = family_names(dataset.root, dataset.models)
        config = method.config.centers
        lookups: list[CentreLookup] = []
        keys = dataset.scene_keys[: args.scenes]
        for i, key in enumerate(keys):
            scene = dataset.scene(key)
            maps = method.predictor.predict(scene)
            center = maps.center.detach().cpu().numpy()
            agnostic = class_agnostic_map(center, maps.exclusive_channels)[:, 0]  # (V, H, W): stage 2's joined map
            gts = [g for g in scene.gt if g.obj_id in dataset.models]
            if not gts:
                continue
            Ks = np.stack([v.K for v in scene.views])
            T_cw = np.stack([v.T_cam_world for v in scene.views])
            T_cm = np.einsum("vij,mjk->vmik", T_cw, np.stack([g.T_world_model for g in gts]))
            H, W = agnostic.shape[1:]
            fract = pile_visibility(method.meshes.many([g.obj_id for g in gts]), T_cm, Ks, H, W).fract  # (V, M)
            targets = [m for m, g in enumerate(gts) if dataset.models[g.obj_id].is_target]
            centres = [transform_points(g.T_world_model, dataset.models[g.obj_id].center[None])[0] for g in gts]
            xy, front = project_points(np.array(centres), Ks, T_cw)  # (V, M, 2), (V, M)
            for v in range(len(scene.views)):
                shown = [m for m in targets if fract[v, m] > args.min_visib and front[v, m]]
                lookups += view_lookups(agnostic[v], xy[v, shown], [names[gts[m].obj_id] for m in shown], config)
            print(f"scene {i + 1}/{len(keys)} {key}", file=sys.stderr, flush=True)
    except BopCenderError as e:
        sys.exit(f"error: {e.format()}")
    if not lookups:
        sys.exit(f"error: no target instance more than {args.min_visib:g} visible in {dataset.root} split {split}")
    print(f"{args.dataset} {split} ({dataset.root}), {len(keys)} scenes, weights {request.weights or 'oracle'};"
          f" instances more than {args.min_visib:g} visible in a view")  # fmt: skip
    print("\n".join(family_table(lookups, args.peak_px)))


if __name__ == "__main__":
    main()
