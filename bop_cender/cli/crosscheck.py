"""``bop-cender crosscheck``: score a results file with bop-cender and with the official BOP toolkit.

The toolkit itself is optional (:mod:`bop_toolkit_adapters`): without it the command says so and exits 0.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bop_cender.cli.options import add_data_options, add_scoring_options, data_overrides

CROSSCHECK_EPILOG = """examples:
  bop-cender crosscheck cendernet_tless-test.csv --data-root ~/bop/tless --toolkit ~/src/bop_toolkit
  EGL_PLATFORM=surfaceless bop-cender crosscheck cendernet_dimo-sim.csv --data-root ~/dimo --toolkit ~/src/bop_toolkit
"""


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``crosscheck`` to ``bop-cender``'s subparsers."""
    fmt = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser("crosscheck", help="score with bop-cender AND the official BOP toolkit, side by side",
                       epilog=CROSSCHECK_EPILOG, formatter_class=fmt)  # fmt: skip
    p.add_argument("results", type=Path, help="BOP results CSV")
    p.add_argument("--toolkit", type=Path, default=None, help="BOP toolkit checkout (bop_toolkit_lib/ + scripts/)")
    add_data_options(p, from_results=True)
    add_scoring_options(p)
    p.add_argument("--out", type=Path, default=None, help="output folder (default: crosscheck_<stem>/ beside the CSV)")
    p.add_argument("--no-vsd", action="store_true", help="skip VSD on the toolkit side (no renderer needed)")
    p.add_argument("--verbose", action="store_true", help="show the toolkit's own log")
    p.set_defaults(func=cmd_crosscheck)


def cmd_crosscheck(args: argparse.Namespace) -> int:
    from bop_cender.data.bop_io import check_output_dir
    from bop_toolkit_adapters.crosscheck import (
        ToolkitUnavailable,
        crosscheck_file,
        format_crosscheck,
        write_pair_differences,
    )

    out = check_output_dir(args.out or args.results.parent / f"crosscheck_{args.results.name.split('.')[0]}")
    try:
        check = crosscheck_file(
            args.results, out, args.toolkit, **data_overrides(args), vsd_delta=args.vsd_delta, with_vsd=not args.no_vsd, quiet=not args.verbose,
            progress=not args.no_progress,
        )  # fmt: skip
    except ToolkitUnavailable as e:
        print(f"crosscheck not run: {e}", file=sys.stderr)
        if args.toolkit is not None:  # a toolkit was asked for and is not there: a failure, not an optional skip
            return 2
        print(
            "(the official toolkit is optional: pass --toolkit DIR, a checkout of thodan/bop_toolkit)", file=sys.stderr
        )
        return 0
    print(format_crosscheck(check))
    if check.differences:
        listed = out / "pair_differences.csv"
        write_pair_differences(listed, check.differences)
        print(f"pairs that differ, largest first: {listed}")
    return 0
