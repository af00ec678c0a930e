"""What stage 3 makes of a network's 3D centres: per GT part, the nearest detected centre and whether it is placed.

The end-to-end gap between a network and the oracle is its centres (``results/accuracy/README.md``, eighteenth
session: oracle centres with the network's curvature score as the oracle). This script says how far a centre may be
off before stage 3 loses the part, the figure a newly trained network should be judged by: every scene of a
DIMO- or T-LESS-layout split runs through the method (``--heatmaps oracle-curvature``, the default: the network's centres, the
oracle's curvature, so that only the centres differ from the oracle), and each target part of the GT gets

- the distance (mm) from its bounding-box centre to the nearest 3D centre of stage 2 (none: infinite);
- whether stage 3 placed an object of its id with its centre within ``--placed-mm`` (3 mm) of it;

printed as a table by the centre's distance (< 5, 5-10, 10-20, >= 20 mm or none) and by object id:

    python scripts/centre_placement.py --data-root DATA/dimo_test --split sim [--weights W] [--scenes K]
    python scripts/centre_placement.py --dataset tless --data-root DATA/tless_test --split test

A part placed within 3 mm of its centre can still be turned (a bracket 17 degrees off); the BOP figures of
``bop-cender run ... --score`` judge poses, this table judges what the centres let stage 3 reach.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bop_cender.centers import Center3D
from bop_cender.errors import BopCenderError
from bop_cender.geometry.poses import transform_points
from bop_cender.runner import HEATMAP_SOURCES, RunRequest, method_for

CENTRE_BINS_MM = (0.0, 5.0, 10.0, 20.0, math.inf)
"""Edges of the table's rows: a network's centre within 5 mm is as good as the oracle's (seed 9002 ``sim``: 40 of
41 such parts placed), 5-20 mm off is where parts are lost to a wrong basin, beyond 20 mm the part has none."""


@dataclass(frozen=True)
class PartPlacement:
    """One GT target part: its object id, the nearest detected centre that may be its, the nearest of any channel
    (T-LESS: one channel per object id; a centre found in another id's channel is a part seen but misnamed) and the
    nearest placed object of its id (mm, between bounding-box centres; ``inf`` where there is none)."""

    obj_id: int
    centre_mm: float
    placed_mm: float
    any_centre_mm: float


def part_placements(
    gt_centres: np.ndarray,
    gt_ids: Sequence[int],
    centres: Sequence[Center3D],
    placed_centres: np.ndarray,
    placed_ids: Sequence[int],
) -> list[PartPlacement]:
    """Per GT part (``gt_centres (M, 3)`` world mm, ``gt_ids (M,)``): the nearest of ``centres`` that may be of its id
    (a shared channel's, DIMO, or its id's channel, T-LESS) and the nearest of the placed objects' centres
    ``placed_centres (P, 3)`` with the part's id ``placed_ids (P,)``."""
    gt_centres = np.asarray(gt_centres, dtype=np.float64).reshape(-1, 3)
    detected = np.array([c.position for c in centres], dtype=np.float64).reshape(-1, 3)
    centre_ids = np.array([-1 if c.obj_id is None else c.obj_id for c in centres], dtype=np.int64)
    placed_centres = np.asarray(placed_centres, dtype=np.float64).reshape(-1, 3)
    placed_ids = np.asarray(placed_ids, dtype=np.int64).reshape(-1)
    out = []
    for centre, obj_id in zip(gt_centres, gt_ids, strict=True):
        mine = detected[(centre_ids == -1) | (centre_ids == obj_id)]
        to_centre = np.linalg.norm(mine - centre, axis=1).min() if len(mine) else math.inf
        same = placed_centres[placed_ids == obj_id]
        to_placed = np.linalg.norm(same - centre, axis=1).min() if len(same) else math.inf
        to_any = np.linalg.norm(detected - centre, axis=1).min() if len(detected) else math.inf
        out.append(PartPlacement(int(obj_id), float(to_centre), float(to_placed), float(to_any)))
    return out


def placement_table(parts: Sequence[PartPlacement], placed_mm: float) -> list[str]:
    """Markdown lines: parts and parts placed within ``placed_mm`` by the centre's distance (``CENTRE_BINS_MM``),
    then by object id: parts, their centres within 5 mm (of their id's channel, and of any channel) and placed."""
    lines = ["| nearest 3D centre | parts | placed |", "|---|---:|---:|"]
    for lo, hi in zip(CENTRE_BINS_MM[:-1], CENTRE_BINS_MM[1:], strict=True):
        inside = [p for p in parts if lo <= p.centre_mm < hi or (p.centre_mm == hi == math.inf)]  # none: the last
        name = f"{lo:g}-{hi:g} mm" if math.isfinite(hi) else f">= {lo:g} mm or none"
        lines.append(f"| {name} | {len(inside)} | {sum(p.placed_mm < placed_mm for p in inside)} |")
    placed = sum(p.placed_mm < placed_mm for p in parts)
    lines.append(f"| all | {len(parts)} | {placed} |")
    near_any = sum(p.any_centre_mm < CENTRE_BINS_MM[1] for p in parts)
    lines.append(f"| any channel's centre < 5 mm | {near_any} | |")
    lines += [
        "",
        "| obj_id | parts | centre within 5 mm | any channel's within 5 mm | placed |",
        "|---:|---:|---:|---:|---:|",
    ]
    for obj_id in sorted({p.obj_id for p in parts}):
        mine = [p for p in parts if p.obj_id == obj_id]
        near = sum(p.centre_mm < CENTRE_BINS_MM[1] for p in mine)
        near_any = sum(p.any_centre_mm < CENTRE_BINS_MM[1] for p in mine)
        lines.append(f"| {obj_id} | {len(mine)} | {near} | {near_any} | {sum(p.placed_mm < placed_mm for p in mine)} |")
    return lines


def scene_placements(output, scene, models: Mapping) -> list[PartPlacement]:
    """:func:`part_placements` of one scene's method output (:class:`~bop_cender.method.SceneOutput`)."""
    gts = [g for g in scene.gt if g.obj_id in models and models[g.obj_id].is_target]
    gt_centres = np.array([transform_points(g.T_world_model, models[g.obj_id].center[None])[0] for g in gts]).reshape(
        -1, 3
    )
    placed = [transform_points(p.T_world_model, models[p.obj_id].center[None])[0] for p in output.placed]
    return part_placements(
        gt_centres, [g.obj_id for g in gts], output.centers, np.array(placed), [p.obj_id for p in output.placed]
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", choices=("dimo", "tless", "bop"), default="dimo", help="layout (default dimo)")
    ap.add_argument("--data-root", default=None, help="dataset root (default: the embedded demo)")
    ap.add_argument("--split", default=None, help="split (default: dimo sim, tless/bop test)")
    ap.add_argument("--weights", default=None, help="network weights (default: the shipped network of the layout)")
    ap.add_argument("--heatmaps", choices=HEATMAP_SOURCES, default="oracle-curvature",
                    help="heatmap source (default oracle-curvature: the network's centres, the oracle's curvature)")  # fmt: skip
    ap.add_argument("--scenes", type=int, default=None, help="only the first K scenes")
    ap.add_argument("--placed-mm", type=float, default=3.0, help="a part is placed within this distance (default 3)")
    args = ap.parse_args()
    if args.scenes is not None and args.scenes < 1:
        ap.error(f"--scenes must be at least 1, got {args.scenes}")
    if not args.placed_mm > 0:
        ap.error(f"--placed-mm must be above 0, got {args.placed_mm}")
    split = args.split or ("sim" if args.dataset == "dimo" else "test")
    try:
        request = RunRequest(args.dataset, args.data_root, split, Path("unused.csv"), heatmaps=args.heatmaps,
                             weights=args.weights, limit_scenes=args.scenes)  # fmt: skip
        request, dataset, method = method_for(request)
        parts: list[PartPlacement] = []
        keys = dataset.scene_keys[: args.scenes]
        for i, key in enumerate(keys):
            scene = dataset.scene(key)
            parts += scene_placements(method.run_scene(scene), scene, dataset.models)
            print(f"scene {i + 1}/{len(keys)} {key}", file=sys.stderr, flush=True)
    except BopCenderError as e:
        sys.exit(f"error: {e.format()}")
    print(f"{args.dataset} {split} ({dataset.root}), {len(keys)} scenes, heatmaps {args.heatmaps}, weights"
          f" {request.weights or 'none'}; placed: an object of the part's id within {args.placed_mm:g} mm")  # fmt: skip
    print("\n".join(placement_table(parts, args.placed_mm)))


if __name__ == "__main__":
    main()
