"""``bop-cender report``: one static page (a folder with ``index.html``) of a run's results, scores and scenes."""

from __future__ import annotations

import argparse
from pathlib import Path

from bop_cender.cli.options import add_data_options, add_protocol_option, add_scoring_options, count, data_overrides

REPORT_EPILOG = """examples:
  bop-cender report run/cendernet-oracle_dimo-sim.csv              # data from the sidecar; -> run/..._report/
  bop-cender report mine_tless-test.csv --data-root ~/bop/tless --out pages/mine
  bop-cender report run/net_bins-test.csv --vis run/vis --max-figures 20
The page (index.html, plots/, scenes/) opens from disk: no server, nothing from the network. It shows the scores as
`score` prints them beside the paper's rows, recall per object, the MSSD / MSPD errors against the thresholds, every
scene worst first with its figure (the run's --vis figure where it made one, else outlines drawn from the rows),
failed scenes, the run's stage timings and settings. An earlier report in --out is replaced.
"""


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``report`` to ``bop-cender``'s subparsers."""
    fmt = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser("report", help="a static HTML page of a run: scores, per-object recall, errors, scenes",
                       epilog=REPORT_EPILOG, formatter_class=fmt)  # fmt: skip
    p.add_argument("results", type=Path, help="BOP results CSV ({method}_{dataset}-{split}.csv)")
    add_data_options(p, from_results=True)
    add_scoring_options(p)
    add_protocol_option(p)
    p.add_argument("--out", type=Path, default=None, help="the page's folder (default: <csv stem>_report beside it)")
    p.add_argument(
        "--vis", type=Path, default=None, metavar="DIR",
        help="the run's --vis figures (default: the folder the run sidecar names); scenes without one get a figure"
        " drawn from their rows",
    )  # fmt: skip
    p.add_argument(
        "--max-figures", type=count("--max-figures", 0), default=None,
        help="figures of at most K scenes, the worst first (default 100; every scene stays in the table)",
    )  # fmt: skip
    p.set_defaults(func=cmd_report)


def cmd_report(args: argparse.Namespace) -> int:
    from bop_cender.report.run_report import DEFAULT_MAX_FIGURES, write_report

    written = write_report(
        args.results, args.out, vis_dir=args.vis,
        max_figures=DEFAULT_MAX_FIGURES if args.max_figures is None else args.max_figures, **data_overrides(args),
        vsd_delta=args.vsd_delta, protocol=args.protocol, progress=not args.no_progress,
    )  # fmt: skip
    print_written(written)
    return 0


def print_written(written) -> None:
    """The page written and where its figures came from (``report`` and ``run --report``)."""
    print(
        f"wrote {written.index} ({written.scenes} scenes; figures: {written.from_run} from the run,"
        f" {written.drawn} drawn from the rows)"
    )
