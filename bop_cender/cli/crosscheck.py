"""``bop-cender crosscheck``: score a results file with bop-cender and with the official BOP toolkit.

The toolkit itself is optional (:mod:`bop_toolkit_adapters`): without it the command says so and exits 2
(:data:`CROSSCHECK_NOT_RUN`), since a cross-check that did not run has checked nothing.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bop_cender.cli.options import add_data_options, add_protocol_option, add_scoring_options, data_overrides

CROSSCHECK_EPILOG = """examples:
  bop-cender crosscheck cendernet_tless-test.csv --data-root ~/bop/tless --toolkit ~/src/bop_toolkit
  EGL_PLATFORM=surfaceless bop-cender crosscheck cendernet_dimo-sim.csv --data-root ~/dimo --toolkit ~/src/bop_toolkit
  bop-cender crosscheck cendernet_tless-test.csv --protocol bop24 --toolkit ~/src/bop_toolkit   # its eval_bop24_pose.py
Exit 0 when the two agree (every score within its tolerance, every MSSD / MSPD pair on both sides and equal to
float noise), 1 when they disagree (the reasons listed), 2 when the toolkit cannot be imported or fails (the
cross-check did not run: not a pass).
"""


#: The exit status when the cross-check could not run (no toolkit): not 0, which would read as a pass.
CROSSCHECK_NOT_RUN = 2
#: The exit status when it ran and the two evaluations disagree (beyond the tolerances, or not comparable).
CROSSCHECK_DISAGREES = 1


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``crosscheck`` to ``bop-cender``'s subparsers."""
    fmt = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser("crosscheck", help="score with bop-cender AND the official BOP toolkit, side by side",
                       epilog=CROSSCHECK_EPILOG, formatter_class=fmt)  # fmt: skip
    p.add_argument("results", type=Path, help="BOP results CSV")
    p.add_argument("--toolkit", type=Path, default=None, help="BOP toolkit checkout (bop_toolkit_lib/ + scripts/)")
    add_data_options(p, from_results=True)
    add_scoring_options(p)
    add_protocol_option(p)
    p.add_argument("--out", type=Path, default=None, help="output folder (default: crosscheck_<stem>/ beside the CSV)")
    p.add_argument("--no-vsd", action="store_true", help="skip VSD on the toolkit side (no renderer needed)")
    p.add_argument("--verbose", action="store_true", help="show the toolkit's own log")
    p.set_defaults(func=cmd_crosscheck)


def cmd_crosscheck(args: argparse.Namespace) -> int:
    from bop_cender.data.bop_io import check_output_dir, require_file
    from bop_cender.errors import ResultsError
    from bop_cender.results.bop_csv import read_bop_results

    require_file(args.results, "results file", ResultsError)
    read_bop_results(args.results)  # a malformed file is said first, with or without the toolkit
    from bop_toolkit_adapters.crosscheck import (
        ToolkitUnavailable,
        crosscheck_file,
        format_crosscheck,
        write_pair_differences,
    )

    out = check_output_dir(args.out or args.results.parent / f"crosscheck_{args.results.name.split('.')[0]}")
    if args.protocol == "bop24":
        return _crosscheck_bop24(args, out)
    listed = out / "pair_differences.csv"
    listed.unlink(missing_ok=True)  # an earlier run's list would read as this run's
    try:
        check = crosscheck_file(
            args.results, out, args.toolkit, **data_overrides(args), vsd_delta=args.vsd_delta, with_vsd=not args.no_vsd, quiet=not args.verbose,
            progress=not args.no_progress,
        )  # fmt: skip
    except ToolkitUnavailable as e:
        # Not run is not passed: a CI script reading exit 0 would take a skipped cross-check for agreement.
        hint = "" if args.toolkit is not None else " (pass --toolkit DIR, a checkout of thodan/bop_toolkit)"
        print(f"error: crosscheck not run: {e}{hint}", file=sys.stderr)
        return CROSSCHECK_NOT_RUN
    print(format_crosscheck(check))
    if check.differences:
        write_pair_differences(listed, check.differences)
        print(f"pairs that differ, largest first: {listed}")
    disagreements = check.disagreements()
    if disagreements:  # exit 0 reads as a pass: only where the two agree
        print(f"verdict: bop-cender and the BOP toolkit DISAGREE ({len(disagreements)}):")
        print("\n".join(f"  {line}" for line in disagreements))
        return CROSSCHECK_DISAGREES
    print("verdict: bop-cender and the BOP toolkit agree")
    return 0


def _crosscheck_bop24(args: argparse.Namespace, out: Path) -> int:
    """``--protocol bop24``: our BOP'24 scores beside the toolkit's own ``eval_bop24_pose.py``, every key and
    per-object AP; exit 0 only where all agree within 1e-9."""
    import shutil

    from bop_cender.eval.score_file import score_file
    from bop_toolkit_adapters.bop24 import crosscheck_bop24, format_bop24_crosscheck
    from bop_toolkit_adapters.runtime import ToolkitUnavailable, import_toolkit

    try:
        import_toolkit(args.toolkit)
    except ToolkitUnavailable as e:
        hint = "" if args.toolkit is not None else " (pass --toolkit DIR, a checkout of thodan/bop_toolkit)"
        print(f"error: crosscheck not run: {e}{hint}", file=sys.stderr)
        return CROSSCHECK_NOT_RUN
    existed = out.exists()
    try:
        scored = score_file(args.results, **data_overrides(args), out_dir=out, progress=not args.no_progress,
                            protocol="bop24")  # fmt: skip
        check = crosscheck_bop24(args.results, scored.report, scored.dataset, out / "toolkit_input", args.toolkit,
                                 quiet=not args.verbose, progress=not args.no_progress)  # fmt: skip
    except BaseException:  # a cross-check that failed leaves nothing half-written
        if not existed:
            shutil.rmtree(out, ignore_errors=True)
        else:
            shutil.rmtree(out / "toolkit_input", ignore_errors=True)
        raise
    print(format_bop24_crosscheck(check))
    if not check.agrees:
        print(f"verdict: bop-cender and the BOP toolkit DISAGREE ({len(check.differences)})")
        return CROSSCHECK_DISAGREES
    print("verdict: bop-cender and the BOP toolkit agree")
    return 0
