"""Ship a training run's weights: copy RUN_DIR/weights.pt into the package with its JSON card.

The card says what the weights are and how they were made: the data (roots, splits, the synth commands
that made them), the seed, the exact training command, epochs, wall time and machine, the validation
figures of the last epoch and the test figures measured by ``bop-cender heatmaps`` (pass their JSON files).

    python scripts/ship_weights.py RUN_DIR --dataset dimo --command "$(cat runs/dimo/command.txt)" \
        --data-note "synth --layout dimo ... --seed 9001" --test heatmaps_sim/heatmaps_dimo-sim.json ...
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import bench_machine
import torch

from bop_cender.net.weights import SHIPPED, load_weights

ROOT = Path(__file__).resolve().parents[1]


def subset_spec(dataset: str, seed: int):
    """The card's fixed subset, small enough for a test to regenerate: DIMO sim variant 0 of one scene, or
    one T-LESS-layout test scene of 5 views. Returns ``(spec, split)``."""
    if dataset == "dimo":
        from bop_cender.synth.write_dimo import DimoSpec

        return DimoSpec(n_scenes=1, variants=(0,), seed=seed, write_real=False, contact_sheets=False), "sim"
    from bop_cender.synth.write_tless import TlessSpec

    return TlessSpec(n_scenes=1, n_views=5, pbr_scenes=0, seed=seed, contact_sheets=False), "test"


def subset_figures(weights_path: Path, dataset: str, seed: int) -> dict:
    """The figures of the weights on the card's fixed subset (:func:`subset_spec`)."""
    import tempfile

    from bop_cender.data.registry import DatasetRequest, open_dataset
    from bop_cender.meshes import MeshCache
    from bop_cender.net.heatmap_eval import evaluate_heatmaps
    from bop_cender.net.predictor import NetPredictor
    from bop_cender.synth.generate import generate

    spec, split = subset_spec(dataset, seed)
    subset = {"scenes": 1, "seed": seed, "split": split}
    subset |= {"variants": [0]} if dataset == "dimo" else {"views_per_scene": 5}
    with tempfile.TemporaryDirectory() as tmp:
        generate(dataset, Path(tmp), spec, progress=False)
        data = open_dataset(DatasetRequest(dataset, Path(tmp), split))
        weights = load_weights(weights_path, dataset=dataset)
        report = evaluate_heatmaps(
            data, NetPredictor(weights), weights.targets, MeshCache(data.models), str(weights_path), progress=False
        )
    return {**subset, "views": report.views, "metrics": report.metrics}


def _pretraining_stages(source: Path, dataset: str) -> list[dict]:
    """The training stages of ``source``: a run folder (one stage: its config and history), or the card of earlier
    shipped weights (its own pretraining stages, then its last run), so that a fine-tune of shipped weights keeps
    their whole history on its card."""
    if source.suffix == ".json":
        card = json.loads(source.read_text())
        earlier = card.get("pretraining") or []
        earlier = [earlier] if isinstance(earlier, dict) else earlier  # cards before chains had one stage
        last = {"run": f"{card['weights']} ({source.name})", "config": card["trained_on"]["config"]}
        return [*earlier, last | {"history": card.get("history", [])}]
    pre = load_weights(source / "weights.pt", dataset=dataset)
    return [{"run": str(source), "config": pre.extra.get("config", {}), "history": pre.extra.get("history", [])}]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--dataset", choices=sorted(SHIPPED), required=True)
    ap.add_argument("--command", required=True, help="the exact training command")
    ap.add_argument("--data-note", action="append", default=[], help="how the data was made (repeatable)")
    ap.add_argument("--test", action="append", default=[], type=Path, help="a heatmaps JSON to put on the card")
    ap.add_argument(
        "--pretrained-run",
        type=Path,
        action="append",
        default=[],
        help="a run folder (or the card of shipped weights) that the weights were fine-tuned from through"
        " --init-weights (its epochs on the card); repeat for a chain, earliest first",
    )
    ap.add_argument("--subset-seed", type=int, default=None,
                    help="seed of the card's fixed subset (default: 9003 DIMO, 9105 T-LESS)")  # fmt: skip
    args = ap.parse_args(argv)
    source = args.run_dir / "weights.pt"
    weights = load_weights(source, dataset=args.dataset)
    history = weights.extra.get("history", [])
    config = weights.extra.get("config", {})
    pretraining = [stage for run in args.pretrained_run for stage in _pretraining_stages(run, args.dataset)]
    pre_history = [h for stage in pretraining for h in stage["history"]]
    target = ROOT / "bop_cender" / "net" / "weights" / SHIPPED[args.dataset]
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(source, target)
    size_mb = target.stat().st_size / 1e6
    if size_mb > 20:
        print(f"error: {target} is {size_mb:.1f} MB; shipped weights must be at most 20 MB", file=sys.stderr)
        return 1
    card = {
        "weights": target.name,
        "dataset": args.dataset,
        "network": weights.model.spec.as_dict(),
        "parameters": sum(p.numel() for p in weights.model.parameters()),
        "targets": weights.targets.__dict__,
        "channel_obj_ids": weights.channel_obj_ids,
        "trained_on": {"data": args.data_note, "config": config},
        "command": args.command,
        "epochs": weights.extra.get("epoch") + len(pre_history),
        "wall_s": round(sum(h.get("wall_s", 0.0) for h in pre_history + history), 1),
        "pretraining": pretraining,
        "machine": f"{bench_machine.cpu_model()}, {bench_machine.usable_cores()} cores, torch {torch.__version__}",
        "validation_last_epoch": history[-1].get("val", {}) if history else {},
        # where stage 3 binarises this network's curvature (train's last validation; see calibrate_curvature.py)
        "curvature_threshold": {
            "value": weights.curvature_threshold,
            "calibrated_on": "as stored in the weights: train's last validation, or calibrate_curvature.py",
        }
        if weights.curvature_threshold is not None
        else None,
        "history": [{k: v for k, v in h.items() if k != "val"} | {"val": h.get("val", {})} for h in history],
        "test": {str(p): json.loads(p.read_text()) for p in args.test},
        "subset": subset_figures(
            target,
            args.dataset,
            (9003 if args.dataset == "dimo" else 9105) if args.subset_seed is None else args.subset_seed,
        ),
        "size_mb": round(size_mb, 2),
    }
    card_path = target.with_suffix(".json")
    card_path.write_text(json.dumps(card, indent=2) + "\n")
    print(f"wrote {target} ({size_mb:.2f} MB) and {card_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
