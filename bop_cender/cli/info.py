"""``bop-cender info``: describe a dataset split."""

from __future__ import annotations

import argparse

from bop_cender.cli.options import add_data_options, announce, data_request

EPILOG = """examples:
  bop-cender info --dataset dimo                      # the embedded synthetic DIMO demo, split real
  bop-cender info --dataset dimo --data-root ~/dimo --split sim
  bop-cender info --dataset tless --data-root ~/bop/tless --split test --n-views 8
  bop-cender info --dataset bop --data-root ~/bop/lmo --split test
"""


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``info`` to ``bop-cender``'s subparsers."""
    p = sub.add_parser(
        "info",
        help="describe a dataset split: scenes, views, objects, symmetries, what the split selected and why",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_data_options(p)
    p.set_defaults(func=cmd_info)


def cmd_info(args: argparse.Namespace) -> int:
    from bop_cender.data.describe import describe
    from bop_cender.datasets import open_with_demo

    ds = open_with_demo(data_request(args), announce=announce)
    print(describe(ds))
    return 0
