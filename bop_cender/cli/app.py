"""The ``bop-cender`` command: the parser of every sub-command (:data:`COMMANDS`) and the error handling.

Thin: each sub-command parses, calls one library function, prints.

Errors from the library (:class:`BopCenderError`) are printed as one line (file: field: message)
with exit code 2; ``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings
from collections.abc import Sequence

from bop_cender import __version__
from bop_cender.cli.info import EPILOG
from bop_cender.errors import BopCenderError

#: The sub-command modules, in ``--help`` order: each has a ``register(subparsers)`` function that adds its
#: sub-command(s). They import only argparse at the top, so ``--help`` stays fast. A new sub-command is a
#: new module in this package and its name here.
COMMANDS = (
    "bop_cender.cli.info",
    "bop_cender.cli.synth",
    "bop_cender.cli.score",
    "bop_cender.cli.compare",
    "bop_cender.cli.report",
    "bop_cender.cli.convert_pvnet",
    "bop_cender.cli.run",
    "bop_cender.cli.train",
    "bop_cender.cli.heatmaps",
    "bop_cender.cli.crosscheck",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bop-cender",
        description="CenDerNet multi-view 6D pose estimation as a BOP method, with its own BOP evaluation harness.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    parser.add_argument("--version", action="version", version=f"bop-cender {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        importlib.import_module(name).register(sub)
    for command in sub.choices.values():  # after the command too (`bop-cender score --debug F`): left unset unless
        # given, so that a --debug before the command stands
        command.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    return parser


def _format_warning(message, category, filename, lineno, line=None) -> str:
    return f"warning: {message}\n"


#: Sub-commands that render a lot and gain from tcmalloc (see bop_cender/launcher.py); ``info`` may
#: generate the embedded demo.
HEAVY_COMMANDS = {"info", "synth", "score", "compare", "report", "run", "train", "heatmaps", "crosscheck"}


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``bop-cender`` console script."""
    command = next((a for a in sys.argv[1:] if not a.startswith("-")), None)
    if argv is None and command in HEAVY_COMMANDS:
        from bop_cender.launcher import reexec_with_tcmalloc

        reexec_with_tcmalloc(sys.argv[1:])
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except BopCenderError as e:  # an option's value refused as it is read (cli.options.count, positive_number)
        print(f"error: {e.format()}", file=sys.stderr)
        return 2
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
