"""Options and messages shared by the sub-commands: the data options, the announcements on stderr."""

from __future__ import annotations

import argparse
import functools
import math
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from bop_cender.data.registry import DatasetRequest


#: ``--dataset`` of the data options: :data:`bop_cender.data.registry.DATASETS` (spelled here so that building the
#: parser imports no data module; tests/data/test_industrial.py checks that they agree).
DATASET_CHOICES = ("dimo", "tless", "bop", "ipd", "xyzibd", "itoddmv")


def count(option: str, minimum: int = 1) -> Callable[[str], int]:
    """An argparse ``type`` for an integer option that must be ``>= minimum`` (a number of scenes, views,
    workers; a seed, ``minimum=0``).

    A value that makes no sense is refused when the command line is read, before any work, with the
    same one-line error as every other (a :class:`~bop_cender.errors.ConfigError` naming the option,
    printed by :func:`bop_cender.cli.app.main`), rather than deep inside the command or not at all.
    """

    def parse(text: str) -> int:
        from bop_cender.errors import ConfigError

        try:
            value = int(text)
        except ValueError:
            raise ConfigError(f"expected an integer, got {text!r}", field=option) from None
        if value < minimum:
            raise ConfigError(f"must be >= {minimum}, got {value}", field=option)
        return value

    parse.__name__ = "integer"  # argparse names the type in its own messages
    return parse


def split_name(option: str) -> Callable[[str], str]:
    """An argparse ``type`` for a split option: a name, not empty (``--split ""``, an unset shell variable, silently
    meant the default split); see :func:`count`."""

    def parse(text: str) -> str:
        from bop_cender.errors import ConfigError

        if not text.strip():
            raise ConfigError(
                "expected a split name, got an empty one (leave the option out for the default)", field=option
            )
        return text

    parse.__name__ = "split"
    return parse


def positive_number(option: str) -> Callable[[str], float]:
    """An argparse ``type`` for a float option that must be finite and > 0 (a VSD delta, a learning rate);
    see :func:`count`."""

    def parse(text: str) -> float:
        from bop_cender.errors import ConfigError

        try:
            value = float(text)
        except ValueError:
            raise ConfigError(f"expected a number, got {text!r}", field=option) from None
        if not (math.isfinite(value) and value > 0):
            raise ConfigError(f"must be a finite number > 0, got {text!r}", field=option)
        return value

    parse.__name__ = "number"
    return parse


def add_data_options(p: argparse.ArgumentParser, *, from_results: bool = False) -> None:
    """Add the dataset options (``--dataset``, ``--data-root``, ``--split``, ``--n-views``, ``--seed``,
    ``--model-type``) to a sub-command; read them back with :func:`data_request`.

    Args:
        from_results: the command reads results files, whose name or run sidecar may say the dataset: every
            option is then optional and overrides what the file says.
    """
    if from_results:
        p.add_argument(
            "--dataset",
            default=None,
            help="dimo | tless | bop | ipd | xyzibd | itoddmv (default: from the file name or sidecar)",
        )
        p.add_argument(
            "--data-root",
            default=None,
            help="dataset root (default: the one the run sidecar names; without a sidecar it must be given, or --demo)",
        )
        p.add_argument(
            "--demo",
            action="store_true",
            help="score against the embedded synthetic dimo / tless demo (generated once); never used unasked",
        )
        p.add_argument(
            "--split", type=split_name("--split"), default=None, help="split (default: from the file name or sidecar)"
        )
        p.add_argument(
            "--n-views", type=count("--n-views"), default=None, help="views per multi-view group of BOP test splits"
        )
        p.add_argument(
            "--seed",
            type=count("--seed", 0),
            default=None,
            help="seed of the view-grouping shuffle (default: sidecar, else 0)",
        )
        p.add_argument("--model-type", default=None, help="models folder variant: cad | eval | reconst (T-LESS: cad)")
        return
    p.add_argument(
        "--dataset",
        choices=DATASET_CHOICES,
        required=True,
        help="dataset layout: dimo | tless | bop, or a BOP-Industrial dataset (multi-sensor): ipd | xyzibd | itoddmv",
    )
    p.add_argument(
        "--data-root", default=None, help="dataset root folder (default: the embedded synthetic demo, generated once)"
    )
    p.add_argument(
        "--split",
        type=split_name("--split"),
        default=None,
        help="dimo: real | sim | train; tless/bop: test | train_pbr | <folder>",
    )
    p.add_argument(
        "--n-views",
        type=count("--n-views"),
        default=None,
        help="views per multi-view group for test splits (default 5)",
    )
    p.add_argument("--seed", type=count("--seed", 0), default=0, help="seed of the view-grouping shuffle (default 0)")
    p.add_argument("--model-type", default=None, help="models folder variant: cad | eval | reconst (T-LESS: cad)")


def data_request(args: argparse.Namespace) -> DatasetRequest:
    """The :class:`~bop_cender.data.registry.DatasetRequest` of a command's data options."""
    from bop_cender.data.registry import DatasetRequest

    return DatasetRequest(
        dataset=args.dataset, root=args.data_root, split=args.split, n_views=args.n_views, seed=args.seed,
        model_type=args.model_type,
    )  # fmt: skip


def data_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """A results command's data options, as the keyword arguments of :func:`bop_cender.eval.score_file.score_file`
    (and of compare, crosscheck): the embedded demo only with ``--demo`` or a sidecar naming the demo's root
    (:func:`bop_cender.datasets.open_results_data`)."""
    from bop_cender.datasets import open_results_data
    from bop_cender.errors import ConfigError

    if args.demo and args.data_root is not None:
        raise ConfigError("give --data-root DIR or --demo, not both", field="--demo")
    return dict(
        dataset=args.dataset, data_root=args.data_root, split=args.split, n_views=args.n_views, seed=args.seed,
        model_type=args.model_type, open_data=functools.partial(open_results_data, demo=args.demo, announce=announce),
    )  # fmt: skip


def add_scoring_options(p: argparse.ArgumentParser) -> None:
    """Add ``--vsd-delta`` and ``--no-progress`` (the commands that score)."""
    p.add_argument(
        "--vsd-delta", type=positive_number("--vsd-delta"), default=None, help="VSD delta in mm (default: 15, ITODD 5)"
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def add_protocol_option(p: argparse.ArgumentParser) -> None:
    """Add ``--protocol bop19|bop24`` (default: the run sidecar's, else bop19)."""
    p.add_argument(
        "--protocol",
        choices=("bop19", "bop24"),
        default=None,
        help="bop19: BOP'19 localisation, AR over VSD, MSSD, MSPD (the top inst_count estimates per target); bop24:"
        " BOP'24/'25 6D detection, mAP over MSSD (diameter and mm) and MSPD, every estimate up to 100 per image"
        " (default: the protocol the run's sidecar names, else bop19)",
    )


def add_executor_options(p: argparse.ArgumentParser, what: str) -> None:
    """``--workers``, ``--executor`` and ``--address``: where ``what`` (scenes, scene folders) are done, the same
    options for ``run`` and ``synth`` (docs/cluster.md)."""
    p.add_argument(
        "--workers",
        type=count("--workers"),
        default=None,
        help="processes, one torch thread each (default 1); with --executor ray: Ray actors, one CPU each (default:"
        f" one per CPU of the cluster, at most one per {what})",
    )
    p.add_argument(
        "--executor",
        choices=("local", "ray"),
        default="local",
        help=f"local: this machine (default); ray: the {what} as Ray tasks on a cluster, their files sent back here"
        ' (pip install -e ".[ray]"; every node needs bop-cender and the data at the same path: docs/cluster.md)',
    )
    p.add_argument(
        "--address",
        default=None,
        metavar="auto|HOST:PORT",
        help="with --executor ray: the cluster (auto: the one started on this machine with `ray start --head`;"
        " HOST:PORT: its head); default: a Ray instance started on this machine for the command",
    )


def announce(line: str) -> None:
    """Tell the user what the command does on their behalf (the embedded demo), on stderr."""
    print(f"[bop-cender] {line}", file=sys.stderr)


def resolve_device(name: str, flag: str = "--device"):
    """The torch device of ``--device auto|cpu|cuda`` (auto: CUDA where torch sees one); ``flag``: the option's
    name in the error.

    Raises:
        ConfigError: ``cuda`` without a CUDA device.
    """
    import torch

    from bop_cender.errors import ConfigError

    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ConfigError("CUDA was asked for but torch sees no CUDA device", field=flag)
    return torch.device(name)
