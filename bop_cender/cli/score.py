"""``bop-cender score``: BOP'19 (AR) or BOP'24/'25 (mAP) scores of a results CSV."""

from __future__ import annotations

import argparse
from pathlib import Path

from bop_cender.cli.options import add_data_options, add_protocol_option, add_scoring_options, data_overrides

SCORE_EPILOG = """examples:
  bop-cender score results/cendernet_tless-test.csv                # dataset, split, data root from the sidecar
  bop-cender score run/cendernet_dimo-sim.csv --data-root ~/dimo    # DIMO: no depth, so no VSD / AR
  bop-cender score my_lmo-test.csv --dataset bop --data-root ~/bop/lmo --out scores/
  bop-cender score mine_dimo-real.csv --demo                        # against the embedded synthetic demo
  bop-cender score results/cendernet_tless-test.csv --protocol bop24  # BOP'24/'25 6D detection: mAP
The data root comes from --data-root, else the run sidecar beside the CSV (written by bop-cender run); the
embedded demo is used only with --demo or a sidecar naming it. A file with no estimate, or none of whose
rows names a target of the data (wrong --data-root?), is refused; under half matching gives a warning.
"""


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``score`` to ``bop-cender``'s subparsers."""
    fmt = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser("score", help="BOP'19 scores (AR, ...) or, --protocol bop24, BOP'24/'25 mAP of a results CSV",
                       epilog=SCORE_EPILOG, formatter_class=fmt)  # fmt: skip
    p.add_argument("results", type=Path, help="BOP results CSV ({method}_{dataset}-{split}.csv)")
    add_data_options(p, from_results=True)
    add_scoring_options(p)
    add_protocol_option(p)
    p.add_argument("--out", type=Path, default=None, help="output folder (default: beside the CSV)")
    p.set_defaults(func=cmd_score)


def cmd_score(args: argparse.Namespace) -> int:
    from contextlib import nullcontext

    from bop_cender.eval.render_process import RenderProcess, render_process_useful

    # The VSD render process is forked before anything heavy is imported here: its torch import (and
    # NumPy's) runs while this process imports the scorer and reads the data.
    with RenderProcess.start() if render_process_useful() else nullcontext() as renderer:
        from bop_cender.eval.score_file import score_file

        scored = score_file(
            args.results, **data_overrides(args),
            vsd_delta=args.vsd_delta, out_dir=args.out, progress=not args.no_progress,
            render_process=renderer or False, protocol=args.protocol,
        )  # fmt: skip
    print_scored(scored, args.results)
    return 0


def print_scored(scored, results: Path) -> None:
    """The score table of a scored file (AR or mAP, by its protocol), the lines that explain it, the files written."""
    from bop_cender.eval.detection_report import DetectionReport
    from bop_cender.eval.score_file import method_name
    from bop_cender.report.summary import MAP_KEYS, format_scores, summary_lines

    report = scored.report
    if isinstance(report, DetectionReport):
        print(format_scores([(method_name(results), report.scores)], keys=MAP_KEYS))
        print()
        print(f"dataset {report.dataset} split {report.split} ({report.root})")
        print("\n".join(report.summary_lines()))
    else:
        print(format_scores([(method_name(results), report.scores)]))
        print()
        print("\n".join(summary_lines(report)))
    print(f"data: {scored.choice.origin}")
    print(f"wrote {scored.scores_path} and {scored.errors_path}")
