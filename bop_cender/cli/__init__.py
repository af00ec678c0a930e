"""The ``bop-cender`` command line: one module per sub-command, each with a ``register(subparsers)``.

Adding a sub-command is adding a module here with ``register(subparsers)`` (it imports only argparse
and this package at the top, so ``--help`` stays fast) and its name to :data:`bop_cender.cli.app.COMMANDS`.
"""

from bop_cender.cli.app import build_parser, main

__all__ = ["build_parser", "main"]
