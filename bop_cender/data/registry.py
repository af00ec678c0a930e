"""Open a dataset split by name: ``dimo``, ``tless`` or any BOP-layout dataset (``bop``).

This is the single entry point the CLI and the runner use; with no data root it falls back
to the embedded synthetic demo dataset of the requested layout.
"""

from __future__ import annotations

import sys
from pathlib import Path

from bop_cender.data.types import Dataset
from bop_cender.errors import ConfigError

DATASETS = ("dimo", "tless", "bop")
DEFAULT_SPLIT = {"dimo": "real", "tless": "test", "bop": "test"}


def open_dataset(
    name: str,
    data_root: str | Path | None = None,
    split: str | None = None,
    *,
    n_views: int | None = None,
    seed: int = 0,
    model_type: str | None = None,
    quiet: bool = False,
) -> Dataset:
    """Open ``name``'s ``split`` under ``data_root`` (or the embedded demo when it is None).

    Args:
        name: ``dimo``, ``tless`` or ``bop``.
        data_root: dataset root; None uses the cached synthetic demo (generated on first use).
        split: split name; defaults per dataset (dimo: real, tless/bop: test).
        n_views: views per multi-view group for BOP-layout test splits (default 5, the paper's).
        seed: seed of the view grouping shuffle.
        model_type: BOP models folder variant (``cad``, ``eval``, ``reconst``; T-LESS default cad).
        quiet: do not announce the demo dataset on stderr.

    Raises:
        ConfigError: unknown dataset name or split.
        DatasetError: the data on disk is missing or inconsistent.
    """
    if name not in DATASETS:
        raise ConfigError(f"unknown dataset {name!r}; expected one of {', '.join(DATASETS)}", field="--dataset")
    split = split or DEFAULT_SPLIT[name]
    if data_root is None:
        if name == "bop":
            raise ConfigError("--dataset bop needs --data-root DIR (a folder in the BOP layout)", field="--data-root")
        from bop_cender.data.demo import ensure_demo

        data_root = ensure_demo(name)
        if not quiet:
            print(
                f"[bop-cender] no --data-root: using the embedded synthetic {name} demo at {data_root}", file=sys.stderr
            )
    root = Path(data_root)
    if name == "dimo":
        from bop_cender.data.dimo import open_dimo

        return open_dimo(root, split)
    if name == "tless":
        from bop_cender.data.tless import open_tless

        return open_tless(root, split, n_views=n_views, seed=seed, model_type=model_type)
    from bop_cender.data.bop import open_bop

    return open_bop(root, split, n_views=n_views, seed=seed, model_type=model_type)
