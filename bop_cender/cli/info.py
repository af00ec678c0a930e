"""``bop-cender info``: describe a dataset split and check the files ``run`` and ``score`` will read.

Every problem found is listed (one line each, ``problem   FILE: FIELD: MESSAGE``), then one line says
what was checked; the exit status is 2 when anything is wrong, 0 when all is readable.
"""

from __future__ import annotations

import argparse

from bop_cender.cli.options import add_data_options, announce, data_request

EPILOG = """examples:
  bop-cender info --dataset dimo                      # the embedded synthetic DIMO demo, split real
  bop-cender info --dataset dimo --data-root ~/dimo --split sim
  bop-cender info --dataset tless --data-root ~/bop/tless --split test --n-views 8
  bop-cender info --dataset bop --data-root ~/bop/lmo --split test
  bop-cender info --dataset tless --data-root ~/bop/tless --deep   # decode every image, not only its header
Besides the description, info checks what run and score read: every model mesh (as their readers read it)
and every colour and depth image (its header by default: the split's size, depth 16-bit; --deep decodes
them all), and the targets file's inst_count against the ground truth, as score does. Every problem is
listed, then a summary line; exit status 2 if there is any, else 0. A mesh without a models_info.json
entry (read by neither run nor score) is a note.
"""


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``info`` to ``bop-cender``'s subparsers."""
    p = sub.add_parser(
        "info",
        help="describe a dataset split (scenes, views, objects, symmetries, what the split selected and why) and "
        "check its meshes and images",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_data_options(p)
    p.add_argument(
        "--deep", action="store_true", help="decode every image in full (default: read their headers alone, quick)"
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_info)


def cmd_info(args: argparse.Namespace) -> int:
    from bop_cender.data.describe import describe, summarise
    from bop_cender.data.file_checks import check_files
    from bop_cender.datasets import open_with_demo
    from bop_cender.eval.targets import targets_file_problems

    progress = not args.no_progress
    ds = open_with_demo(data_request(args), announce=announce)
    summary = summarise(ds, progress=progress, keep_going=True)
    print(describe(ds, summary=summary), flush=True)
    scenes = [ds.scene(key) for key in summary.loaded]
    check = check_files(ds, scenes, deep=args.deep, progress=progress)
    check.problems[:0] = summary.problems
    check.problems += targets_file_problems(ds, scenes)
    for note in check.notes:
        print(f"note      {note}")
    for problem in check.problems:
        print(f"problem   {problem}")
    print(check.summary())
    return 2 if check.problems else 0
