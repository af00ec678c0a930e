"""Which score makes the best BOP'24 detection submission: the mAP of each way to score the same run's estimates.

Usage:
    python scripts/detection_scores.py --dataset dimo --data-root DATA --split sim --heatmaps oracle \\
        [--weights W.pt] [--limit-scenes N] [--out FILE.md]

AP rewards a submission whose scores put right poses before wrong ones, across the whole dataset. The method is run
once per scene for the 6D-detection task (``run --task detection``: no instance counts, no object ids), and its
estimates are written with each candidate score, then scored with the BOP'24 protocol:

- ``fit x seen`` (what ``run`` writes): ``1 / (1 + cost)`` of stage 3 times the centre heatmap at the object's centre
  in that image (how well that image shows it, which also orders the per-image cap);
- ``fit``: ``1 / (1 + cost)`` alone, the same in every image;
- ``seen``: the centre heatmap in that image alone;
- ``fit x views``: ``1 / (1 + cost)`` times the mean over the scene's views of the centre heatmap (the multi-view
  evidence for the centre, the same in every image).

Prints one table (``bop24_mAP``, ``bop25_mAP_mm`` and the others per score) and writes it to ``--out``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCORES = ("fit x seen", "fit", "seen", "fit x views")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dataset", required=True, choices=("dimo", "tless", "bop"))
    parser.add_argument("--data-root", required=True)
    parser.add_argument("--split", default=None)
    parser.add_argument("--heatmaps", default="oracle", choices=("oracle", "net"))
    parser.add_argument("--weights", default=None)
    parser.add_argument("--limit-scenes", type=int, default=None)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from bop_cender.data.registry import DEFAULT_SPLIT
    from bop_cender.estimates import ObjectEstimate
    from bop_cender.eval.scoring_bop24 import score_detections
    from bop_cender.progress import progress_bar
    from bop_cender.results.bop_csv import scene_estimates_to_rows
    from bop_cender.runner.build import method_for
    from bop_cender.runner.request import RunRequest

    split = args.split or DEFAULT_SPLIT[args.dataset]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / f"rescored_{args.dataset}-{split}.csv"  # never written: the rows are scored in memory
        request = RunRequest(args.dataset, args.data_root, split, out, heatmaps=args.heatmaps,
                             weights=args.weights, task="detection")  # fmt: skip
        request, dataset, method = method_for(request)
        keys = dataset.scene_keys[: args.limit_scenes]
        rows: dict[str, list] = {name: [] for name in SCORES}
        for key in progress_bar(keys, desc="scenes", unit="scene"):
            scene = dataset.scene(key)
            estimate = method.run_scene(scene).estimate
            for name in SCORES:
                objects = tuple(_rescored(o, name, ObjectEstimate) for o in estimate.objects)
                rows[name] += scene_estimates_to_rows(scene, replace(estimate, objects=objects))
        results = {name: score_detections(r, dataset, progress=False).scores for name, r in rows.items()}
    keys_shown = ("bop24_mAP", "bop24_mAP_mssd", "bop24_mAP_mspd", "bop25_mAP", "bop25_mAP_mm")
    lines = [
        f"### Detection scores, {args.dataset} {split} ({len(keys)} scenes of {args.data_root}), {args.heatmaps} heatmaps",
        "",
        "| score | " + " | ".join(keys_shown) + " |",
        "|---|" + "---:|" * len(keys_shown),
    ]
    lines += [f"| {name} | " + " | ".join(f"{results[name][k]:.3f}" for k in keys_shown) + " |" for name in SCORES]
    print("\n".join(lines))
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text("\n".join(lines) + "\n")
        print(f"wrote {args.out}")
    return 0


def _rescored(obj, name: str, ObjectEstimate):  # noqa: N803 - the class, passed in
    """``obj`` with the score ``name`` (module docstring); ``obj.score`` is the fit, ``image_scores`` the seen."""
    seen = dict(obj.image_scores)
    views = float(np.mean(list(seen.values()))) if seen else 1.0
    if name == "fit x seen":
        return obj
    if name == "fit":
        return ObjectEstimate(obj.obj_id, obj.T_world_model, obj.score, {})
    if name == "seen":
        return ObjectEstimate(obj.obj_id, obj.T_world_model, 1.0, seen)
    return ObjectEstimate(obj.obj_id, obj.T_world_model, obj.score * views, {})


if __name__ == "__main__":
    sys.exit(main())
