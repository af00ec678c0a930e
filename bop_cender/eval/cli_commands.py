"""``bop-cender`` sub-commands of the evaluation: score, compare, convert-pvnet.

Thin: each parses its options, calls one library function and prints. Heavy imports (torch, the
renderer, matplotlib) happen inside the commands, so ``bop-cender --help`` stays fast.
"""

from __future__ import annotations

import argparse
from pathlib import Path

SCORE_EPILOG = """examples:
  bop-cender score results/cendernet_tless-test.csv                # dataset, split from the name / sidecar
  bop-cender score run/cendernet_dimo-sim.csv --data-root ~/dimo    # DIMO: no depth, so no VSD / AR
  bop-cender score my_lmo-test.csv --dataset bop --data-root ~/bop/lmo --out scores/
"""
COMPARE_EPILOG = """examples:
  bop-cender compare cendernet_tless-test.csv cosypose114533-eccv2020_tless-test-primesense.csv \\
      pvnet_tless-test.csv --reference paper --data-root ~/bop/tless --out tables/
  bop-cender compare tables/scores_cendernet_dimo-sim.json --reference paper
"""


def register(sub: argparse._SubParsersAction) -> None:
    """Add score, compare and convert-pvnet to ``bop-cender``'s subparsers."""
    fmt = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser("score", help="BOP'19 scores (AR, AR_VSD, AR_MSSD, AR_MSPD, ...) of a results CSV",
                       epilog=SCORE_EPILOG, formatter_class=fmt)  # fmt: skip
    p.add_argument("results", type=Path, help="BOP results CSV ({method}_{dataset}-{split}.csv)")
    data_args(p)
    p.add_argument("--out", type=Path, default=None, help="output folder (default: beside the CSV)")
    p.set_defaults(func=cmd_score)

    p = sub.add_parser("compare", help="one table (markdown, CSV, bar chart) of several methods' scores",
                       epilog=COMPARE_EPILOG, formatter_class=fmt)  # fmt: skip
    p.add_argument("inputs", nargs="+", type=Path, help="results CSVs (scored here) and/or scores JSONs")
    p.add_argument("--reference", default=None, help="'paper': add the CenDerNet paper's reported numbers (or a CSV)")
    data_args(p)
    p.add_argument("--out", type=Path, default=Path("."), help="output folder (default: .)")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("convert-pvnet", help="PVNet-style 3x4 poses (t in metres) -> BOP results CSV (mm)")
    p.add_argument("input", type=Path, help="folder of {scene}_{im}_{obj}.npy / {scene}/{im}_{obj}.npy, or a JSON file")
    p.add_argument("--out", type=Path, required=True, help="output CSV, a BOP name such as pvnet_tless-test.csv")
    p.add_argument("--dataset-root", type=Path, default=None, help="check object ids against this dataset's models")
    p.set_defaults(func=cmd_convert_pvnet)


def data_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--dataset", default=None, help="dimo | tless | bop (default: from the file name or sidecar)")
    p.add_argument("--data-root", default=None, help="dataset root (default: sidecar, else the embedded demo)")
    p.add_argument("--split", default=None, help="split (default: from the file name or sidecar)")
    p.add_argument("--n-views", type=int, default=None, help="views per multi-view group of BOP test splits")
    p.add_argument("--vsd-delta", type=float, default=None, help="VSD delta in mm (default: 15, ITODD 5)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def cmd_score(args: argparse.Namespace) -> int:
    from contextlib import nullcontext

    from bop_cender.eval.render_process import RenderProcess, render_process_useful

    # The VSD render process is forked before anything heavy is imported here: its torch import (and
    # NumPy's) runs while this process imports the scorer and reads the data.
    with RenderProcess.start() if render_process_useful() else nullcontext() as renderer:
        from bop_cender.eval.report import format_scores, summary_lines
        from bop_cender.eval.score_file import method_name, score_file

        scored = score_file(
            args.results, dataset=args.dataset, data_root=args.data_root, split=args.split, n_views=args.n_views,
            vsd_delta=args.vsd_delta, out_dir=args.out, progress=not args.no_progress,
            render_process=renderer or False,
        )  # fmt: skip
    print(format_scores([(method_name(args.results), scored.report.scores)]))
    print()
    print("\n".join(summary_lines(scored.report)))
    print(f"data: {scored.choice.origin}")
    print(f"wrote {scored.scores_path} and {scored.errors_path}")
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    from bop_cender.eval.tables import compare

    comparison = compare(
        args.inputs, reference=args.reference, dataset=args.dataset, data_root=args.data_root, split=args.split,
        n_views=args.n_views, vsd_delta=args.vsd_delta, out_dir=args.out, progress=not args.no_progress,
    )  # fmt: skip
    print(comparison.markdown())
    print("wrote " + ", ".join(str(p) for p in comparison.files.values()))
    return 0


def cmd_convert_pvnet(args: argparse.Namespace) -> int:
    from bop_cender.eval.convert_pvnet import convert_pvnet

    known = None
    if args.dataset_root is not None:
        known = _model_ids(args.dataset_root)
    rows = convert_pvnet(args.input, args.out, known_obj_ids=known)
    print(f"wrote {len(rows)} estimates to {args.out}")
    return 0


def _model_ids(root: Path) -> list[int]:
    """Object ids of a dataset's evaluation models (``models_eval/``, else ``models/`` or ``models_cad/``)."""
    from bop_cender.data.bop_io import as_int, load_json
    from bop_cender.errors import DatasetError

    for name in ("models_eval", "models", "models_cad"):
        path = root / name / "models_info.json"
        if path.is_file():
            return sorted(as_int(k, path, repr(k), strings=True) for k in load_json(path))
    raise DatasetError("no models_eval/, models/ or models_cad/ with a models_info.json", file=root)
