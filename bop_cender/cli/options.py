"""Options and messages shared by the sub-commands: the data options, the announcements on stderr."""

from __future__ import annotations

import argparse
import sys


def add_data_options(p: argparse.ArgumentParser) -> None:
    """Add the dataset options (``--dataset``, ``--data-root``, ``--split``, ``--n-views``, ``--seed``,
    ``--model-type``) to a sub-command."""
    p.add_argument("--dataset", choices=("dimo", "tless", "bop"), required=True, help="dataset layout")
    p.add_argument(
        "--data-root", default=None, help="dataset root folder (default: the embedded synthetic demo, generated once)"
    )
    p.add_argument("--split", default=None, help="dimo: real | sim | train; tless/bop: test | train_pbr | <folder>")
    p.add_argument("--n-views", type=int, default=None, help="views per multi-view group for test splits (default 5)")
    p.add_argument("--seed", type=int, default=0, help="seed of the view-grouping shuffle (default 0)")
    p.add_argument("--model-type", default=None, help="models folder variant: cad | eval | reconst (T-LESS: cad)")


def add_results_data_options(p: argparse.ArgumentParser) -> None:
    """The data options of the commands that score results files (the dataset may come from the file)."""
    p.add_argument("--dataset", default=None, help="dimo | tless | bop (default: from the file name or sidecar)")
    p.add_argument("--data-root", default=None, help="dataset root (default: sidecar, else the embedded demo)")
    p.add_argument("--split", default=None, help="split (default: from the file name or sidecar)")
    p.add_argument("--n-views", type=int, default=None, help="views per multi-view group of BOP test splits")
    p.add_argument("--vsd-delta", type=float, default=None, help="VSD delta in mm (default: 15, ITODD 5)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def announce(line: str) -> None:
    """Tell the user what the command does on their behalf (the embedded demo), on stderr."""
    print(f"[bop-cender] {line}", file=sys.stderr)
