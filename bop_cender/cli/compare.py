"""``bop-cender compare``: one table of several methods' scores."""

from __future__ import annotations

import argparse
from pathlib import Path

from bop_cender.cli.options import add_data_options, add_protocol_option, add_scoring_options, data_overrides

COMPARE_EPILOG = """examples:
  bop-cender compare cendernet_tless-test.csv cosypose114533-eccv2020_tless-test-primesense.csv \\
      pvnet_tless-test.csv --reference paper --data-root ~/bop/tless --out tables/
  bop-cender compare tables/scores_cendernet_dimo-sim.json --reference paper
  bop-cender compare mine_tless-test.csv theirs_tless-test.csv --protocol bop24 --data-root ~/bop/tless   # mAP
"""


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``compare`` to ``bop-cender``'s subparsers."""
    fmt = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser("compare", help="one table (markdown, CSV, bar chart) of several methods' scores",
                       epilog=COMPARE_EPILOG, formatter_class=fmt)  # fmt: skip
    p.add_argument("inputs", nargs="+", type=Path, help="results CSVs (scored here) and/or scores JSONs")
    p.add_argument("--reference", default=None, help="'paper': add the CenDerNet paper's reported numbers (or a CSV)")
    add_data_options(p, from_results=True)
    add_scoring_options(p)
    add_protocol_option(p)
    p.add_argument("--out", type=Path, default=Path("."), help="output folder (default: .)")
    p.set_defaults(func=cmd_compare)


def cmd_compare(args: argparse.Namespace) -> int:
    from bop_cender.report.tables import compare

    comparison = compare(
        args.inputs, reference=args.reference, **data_overrides(args), vsd_delta=args.vsd_delta, out_dir=args.out, progress=not args.no_progress,
        protocol=args.protocol,
    )  # fmt: skip
    print(comparison.markdown())
    print("wrote " + ", ".join(str(p) for p in comparison.files.values()))
    for source, scores in comparison.scores.items():
        print(f"scores of {source}: {scores}")
    return 0
