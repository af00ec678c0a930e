"""The ``bop-cender`` command line. Thin: it parses, calls one library function, prints.

Errors from the library (:class:`BopCenderError`) are printed as one line (file: field: message)
with exit code 2; ``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings
from collections.abc import Sequence

from bop_cender.errors import BopCenderError

EPILOG = """examples:
  bop-cender info --dataset dimo                      # the embedded synthetic DIMO demo, split real
  bop-cender info --dataset dimo --data-root ~/dimo --split sim
  bop-cender info --dataset tless --data-root ~/bop/tless --split test --n-views 8
  bop-cender info --dataset bop --data-root ~/bop/lmo --split test
"""


def _add_dataset_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--dataset", choices=("dimo", "tless", "bop"), required=True, help="dataset layout")
    p.add_argument(
        "--data-root", default=None, help="dataset root folder (default: the embedded synthetic demo, generated once)"
    )
    p.add_argument("--split", default=None, help="dimo: real | sim | train; tless/bop: test | train_pbr | <folder>")
    p.add_argument("--n-views", type=int, default=None, help="views per multi-view group for test splits (default 5)")
    p.add_argument("--seed", type=int, default=0, help="seed of the view-grouping shuffle (default 0)")
    p.add_argument("--model-type", default=None, help="models folder variant: cad | eval | reconst (T-LESS: cad)")


def cmd_info(args: argparse.Namespace) -> int:
    from bop_cender.data.describe import describe
    from bop_cender.data.registry import open_dataset
    from bop_cender.datasets import resolve_data_root

    root = resolve_data_root(args.dataset, args.data_root, announce=announce)
    ds = open_dataset(args.dataset, root, args.split, n_views=args.n_views, seed=args.seed, model_type=args.model_type)
    print(describe(ds))
    return 0


def announce(line: str) -> None:
    """Tell the user what the command does on their behalf (the embedded demo), on stderr."""
    print(f"[bop-cender] {line}", file=sys.stderr)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bop-cender",
        description="CenDerNet multi-view 6D pose estimation as a BOP method, with its own BOP evaluation harness.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    p = sub.add_parser(
        "info",
        help="describe a dataset split: scenes, views, objects, symmetries, what the split selected and why",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_dataset_args(p)
    p.set_defaults(func=cmd_info)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


#: Modules with a ``register(subparsers)`` function that adds their sub-commands (synth, score, ...); they
#: import only argparse at the top, so ``--help`` stays fast.
COMMAND_MODULES = ("bop_cender.synth.cli_commands", "bop_cender.eval.cli_commands", "bop_toolkit_adapters.cli_commands")


def _format_warning(message, category, filename, lineno, line=None) -> str:
    return f"warning: {message}\n"


#: Sub-commands that render a lot and gain from tcmalloc (see bop_cender/launcher.py); ``info`` may
#: generate the embedded demo.
HEAVY_COMMANDS = {"info", "synth", "score", "compare", "run", "train", "crosscheck"}


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``bop-cender`` console script."""
    command = next((a for a in sys.argv[1:] if not a.startswith("-")), None)
    if argv is None and command in HEAVY_COMMANDS:
        from bop_cender.launcher import reexec_with_tcmalloc

        reexec_with_tcmalloc(sys.argv[1:])
    parser = build_parser()
    args = parser.parse_args(argv)
    warnings.formatwarning = _format_warning
    try:
        return int(args.func(args) or 0)
    except BopCenderError as e:
        if args.debug:
            raise
        print(f"error: {e.format()}", file=sys.stderr)
        return 2
    except OSError as e:  # the file system said no (an output folder that is a file, a full disk, no permission)
        if args.debug:
            raise
        where = f"{e.filename}: " if e.filename else ""
        print(f"error: {where}{e.strerror or e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
