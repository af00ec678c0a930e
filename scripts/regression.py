"""Regression check of the BOP scorer against committed tables and the official toolkit's numbers.

Usage:
    python scripts/regression.py                    # check: exit 1 with a diff table on any drift
    python scripts/regression.py --update           # rewrite results/regression/{scores,errors,matches}.csv
    EGL_PLATFORM=surfaceless PYTHONPATH=<vispy, pypng> \\
    python scripts/regression.py --anchor TOOLKIT   # recompute toolkit_anchor_*.csv with the official toolkit
    python scripts/regression.py --anchor TOOLKIT --protocol bop24   # only the BOP'24 anchor (no renderer needed)

The fixture, the tables and the tolerances are described in ``bop_cender/regression.py``. The
anchor is made by the toolkit's own ``eval_calc_errors.py`` / ``eval_calc_scores.py`` (run in-process on
an export of the fixture, see ``bop_toolkit_adapters``); the toolkit is not part of this repository.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from bop_cender.regression import (
    RESULTS_NAME,
    anchor_tables,
    compare_tables,
    format_problems,
    run_regression,
    write_tables,
)

#: The committed tables, in the repository (the package does not read them).
TABLES_DIR = Path(__file__).resolve().parents[1] / "results" / "regression"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--update", action="store_true", help="rewrite our committed tables deliberately")
    parser.add_argument("--anchor", type=Path, default=None, metavar="TOOLKIT", help="recompute the toolkit anchor")
    parser.add_argument("--protocol", choices=("both", "bop19", "bop24"), default="both",
                        help="which anchors --anchor recomputes (bop19 needs the toolkit's VSD renderer)")  # fmt: skip
    parser.add_argument("--tables", type=Path, default=TABLES_DIR, help="tables folder (default results/regression)")
    parser.add_argument("--work", type=Path, default=None, help="keep the fixture here (default: a temporary folder)")
    args = parser.parse_args(argv)
    if not args.update and args.anchor is None and not args.tables.is_dir():  # a typo read as four drifted tables
        print(f"error: {args.tables}: --tables: tables folder not found", file=sys.stderr)
        return 2
    scripts = None
    if args.anchor is not None:  # checked before the fixture is scored
        if not args.anchor.is_dir():
            print(f"error: {args.anchor}: --anchor: the official toolkit's folder not found", file=sys.stderr)
            return 2
        from bop_toolkit_adapters.runtime import ToolkitUnavailable, import_toolkit

        try:
            _, scripts = import_toolkit(args.anchor)
        except ToolkitUnavailable as e:  # a folder that is not the toolkit, or one missing its dependencies
            print(f"error: {args.anchor}: --anchor: {e}", file=sys.stderr)
            return 2

    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        run = run_regression(work)
        if args.anchor is not None:
            return _anchor(run, work, scripts, args.tables, args.protocol)
    if args.update:
        for path in write_tables(run, args.tables):
            print(f"wrote {path}")
        return 0
    problems = compare_tables(run, args.tables)
    if problems:
        print(format_problems(problems))
        return 1
    n_pairs = sum(len(r.gt_ids) for r in run.report.records)
    print(
        f"regression OK: {len(run.report.records)} estimates, {n_pairs} pairs, every recall and score equal to"
        f" {args.tables}/ and to the official toolkit's anchor (AR {run.report.scores['AR']:.6f}); BOP'24:"
        f" {run.detection.counts.evaluated} estimates, every AP and score equal too"
        f" (bop24_mAP {run.detection.scores['bop24_mAP']:.6f})"
    )
    return 0


def _anchor(run, work: Path, scripts, tables: Path, protocol: str = "both") -> int:
    from bop_cender.data.bop_io import write_text_atomic
    from bop_cender.data.registry import DatasetRequest, open_dataset
    from bop_cender.regression import ANCHOR_BOP24, RESULTS_NAME_BOP24, bop24_table
    from bop_toolkit_adapters.bop24 import evaluate_bop24, export_bop24
    from bop_toolkit_adapters.export import export_for_toolkit
    from bop_toolkit_adapters.runtime import evaluate, vsd_renderer_available

    why = vsd_renderer_available() if protocol != "bop24" else None
    if why is not None:
        print(f"the toolkit's VSD renderer is not available ({why}): the BOP'19 anchor needs it", file=sys.stderr)
        return 2
    dataset = open_dataset(DatasetRequest("tless", work / "tless", "test"))
    if protocol != "bop19":
        toolkit = evaluate_bop24(export_bop24(dataset, work / RESULTS_NAME_BOP24, work / "toolkit24", False), scripts)
        write_text_atomic(tables / ANCHOR_BOP24, bop24_table(toolkit["scores"], toolkit["object_aps"]))
        print(f"wrote {tables / ANCHOR_BOP24}")
    if protocol == "bop24":
        return 0
    export = export_for_toolkit(dataset, work / RESULTS_NAME, work / "toolkit", progress=False)
    scores = evaluate(export, scripts, with_vsd=True)
    for name, text in anchor_tables(scores.errors, scores.recalls, scores.average_recalls).items():
        write_text_atomic(tables / name, text)
        print(f"wrote {tables / name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
