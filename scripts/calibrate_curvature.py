"""Calibrate a weights file's curvature threshold: the binarisation with the best F1 on validation views.

``bop-cender train`` stores this threshold in every weights file it writes (``curvature_threshold``, from the
epoch's validation); this script adds or refreshes it in a file written before that existed, or calibrates
on other views. Stage 3 binarises the network's curvature there (``poses.network.t_b`` None, the
default) instead of at ``t_b``, which suits the renderer's sharp curvature but breaks a network's softer
edges into fragments. Only the threshold changes: the network's parameters are copied bit for bit.

    python scripts/calibrate_curvature.py bop_cender/net/weights/dimo.pt --dataset dimo \\
        --data-root data/dimo_val --split sim [--out OTHER.pt]

Prints the F1 at ``t_b`` and at the calibrated threshold. Calibrate on validation views, never on the test
split whose figures you report. Where the weights have a JSON card beside them (``WEIGHTS.json``, as
``ship_weights.py`` writes it), its threshold entry is refreshed too.

``--for-split NAME`` stores the threshold for runs on split ``NAME`` only (the weights' general threshold stays):
a network's best binarisation moves with the camera and its domain (DIMO's ``real`` camera against ``sim``), and
``run`` on split ``NAME`` then binarises there:

    python scripts/calibrate_curvature.py bop_cender/net/weights/dimo.pt --dataset dimo \
        --data-root data/dimo_val --split real --for-split real
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

import torch

from bop_cender.data.bop_io import write_text_atomic
from bop_cender.data.registry import DatasetRequest, open_dataset
from bop_cender.errors import BopCenderError, ConfigError
from bop_cender.meshes import MeshCache
from bop_cender.net.heatmap_eval import evaluate_heatmaps
from bop_cender.net.predictor import NetPredictor
from bop_cender.net.weights import CURVATURE_THRESHOLD, CURVATURE_THRESHOLD_BY_SPLIT, load_weights, save_weights


def calibrate(
    weights_path: Path,
    dataset: str,
    data_root: Path,
    split: str,
    out: Path,
    for_split: str | None = None,
    command: str | None = None,
) -> dict:
    """Measure the best-F1 threshold of ``weights_path`` on ``data_root``/``split`` and write the weights with it
    to ``out`` (atomically): as their general threshold, or (``for_split``) as that for runs on split ``for_split``;
    and, written in place, on the weights' card where they have one (:func:`card_with_threshold`, ``command`` the
    one to state there). Returns the figures (``curvature_f1`` at t_b, ``curvature_best_*``) and ``card`` (the card
    written, or None).

    Raises:
        ConfigError: the split has no ground truth, or the best threshold is not inside (0, 1) (a network
            whose curvature ranks nothing: binarising it anywhere is as good as at 0); the weights' card is
            damaged; ``out`` is another file whose card (of the weights there before) would be left stating
            another network. Each before anything is written.
    """
    in_place = Path(out).resolve() == Path(weights_path).resolve()
    card = read_card(out)  # first: a damaged card stops the calibration before minutes of evaluation
    if card is not None and not in_place:
        raise ConfigError(
            f"a card of the weights now at {out} sits beside them; writing other weights there would leave it"
            " describing another network: remove the card, or write elsewhere",
            file=out.with_suffix(".json"),
            field="--out",
        )
    weights = load_weights(weights_path, dataset=dataset)
    data = open_dataset(DatasetRequest(dataset, data_root, split))
    report = evaluate_heatmaps(
        data, NetPredictor(weights), weights.targets, MeshCache(data.models), str(weights_path), progress=True
    )
    if not report.metrics:
        raise ConfigError(f"split {split!r} has no ground truth to calibrate on", file=data_root, field="--split")
    threshold = report.metrics.get("curvature_best_threshold")
    if threshold is None:
        raise ConfigError(
            f"split {split!r} shows no curvature edge in its ground truth", file=data_root, field="--split"
        )
    if not 0.0 < threshold < 1.0:
        raise ConfigError(f"no usable threshold: the best F1 is at {threshold:g}", file=weights_path)
    payload = torch.load(weights_path, map_location="cpu", weights_only=True)
    if for_split is None:
        payload[CURVATURE_THRESHOLD] = float(threshold)
    else:
        payload[CURVATURE_THRESHOLD_BY_SPLIT] = {**(payload.get(CURVATURE_THRESHOLD_BY_SPLIT) or {}),
                                                 for_split: float(threshold)}  # fmt: skip
    save_weights(out, payload)
    figures = {k: v for k, v in report.metrics.items() if k.startswith("curvature_")} | {"views": report.views}
    if card is None:
        return figures | {"card": None}
    card_path = out.with_suffix(".json")
    try:
        write_text_atomic(card_path, json.dumps(card_with_threshold(card, data_root, split, for_split, figures, command),
                                                indent=2) + "\n")  # fmt: skip
    except OSError as exc:
        raise ConfigError(
            f"the weights were written, their card not ({exc}): it still states the old threshold", file=card_path
        ) from None
    return figures | {"card": str(card_path)}


def read_card(weights: Path) -> dict | None:
    """The JSON card of ``weights`` (``WEIGHTS.json`` beside them, as ``ship_weights.py`` writes it), None where there
    is none (or that JSON is not this file's card: its ``weights`` names another file).

    Raises:
        ConfigError: the card is there but not readable JSON, or its threshold entries are not objects."""
    card_path = weights.with_suffix(".json")
    if not card_path.is_file():
        return None
    try:
        card = json.loads(card_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"the weights' card is not readable JSON ({exc}); nothing written", file=card_path) from None
    if not isinstance(card, dict) or card.get("weights") != weights.name:
        return None
    for key in ("curvature_threshold", "curvature_threshold_by_split"):
        if card.get(key) is not None and not isinstance(card[key], dict):
            raise ConfigError(f"expected an object, got {type(card[key]).__name__}; nothing written", file=card_path,
                              field=key)  # fmt: skip
    return card


def card_with_threshold(
    card: dict, data_root: Path, split: str, for_split: str | None, figures: dict, command: str | None
) -> dict:
    """``card`` with the new threshold, so that a card never states another threshold than its weights hold (the
    shipped weights' test checks both): its ``curvature_threshold`` (or, ``for_split``, that split's entry of
    ``curvature_threshold_by_split``, the others kept) becomes the value, where and how it was calibrated, and the
    F1 at ``t_b`` and at the value; a ``why`` already there stays."""
    card = dict(card)
    entry = {
        "value": round(float(figures["curvature_best_threshold"]), 3),
        "calibrated_on": f"{data_root} split {split} ({int(figures['views'])} validation views): the threshold with"
        " the best curvature F1",
        "command": command or "python scripts/calibrate_curvature.py",
        "curvature_f1_at_t_b": round(float(figures["curvature_f1"]), 3),
        "curvature_f1_at_value": round(float(figures["curvature_best_f1"]), 3),
    }
    if for_split is None:  # read_card checked both entries are objects where present
        entries, key = card, "curvature_threshold"
    else:
        entries = card["curvature_threshold_by_split"] = dict(card.get("curvature_threshold_by_split") or {})
        key = for_split
    old = entries.get(key)
    if isinstance(old, dict) and "why" in old:
        entry["why"] = old["why"]
    entries[key] = entry
    return card


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("weights", type=Path)
    ap.add_argument("--dataset", choices=("dimo", "tless", "bop"), required=True)
    ap.add_argument("--data-root", type=Path, required=True, help="a dataset with GT (validation views)")
    ap.add_argument("--split", required=True)
    ap.add_argument("--out", type=Path, default=None, help="where to write (default: the weights file itself)")
    ap.add_argument("--for-split", default=None, metavar="NAME",
                    help="store the threshold for runs on split NAME only (default: as the general threshold)")  # fmt: skip
    args = ap.parse_args(argv)
    if args.for_split is not None and not args.for_split.strip():
        print("error: --for-split: expected a split name", file=sys.stderr)
        return 2
    try:
        command = "python scripts/calibrate_curvature.py " + " ".join(shlex.quote(a) for a in (argv or sys.argv[1:]))
        figures = calibrate(
            args.weights, args.dataset, args.data_root, args.split, args.out or args.weights, args.for_split, command
        )
    except BopCenderError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # the weights file not writable, the disk full: before the card
        print(f"error: {args.out or args.weights}: not written ({exc})", file=sys.stderr)
        return 2
    print(
        f"{int(figures['views'])} views: curvature F1 {figures['curvature_f1']:.3f} at t_b,"
        f" {figures['curvature_best_f1']:.3f} at {figures['curvature_best_threshold']:.3f};"
        f" wrote {args.out or args.weights} ({CURVATURE_THRESHOLD}"
        + (f" for split {args.for_split}" if args.for_split else "")
        + f" {figures['curvature_best_threshold']:.3f})"
        + (f" and its card {figures['card']}" if figures["card"] else "")
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
