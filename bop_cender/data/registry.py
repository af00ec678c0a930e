"""Open a dataset split by name: ``dimo``, ``tless`` or any BOP-layout dataset (``bop``).

This is the single entry point the CLI and the runner use. It needs a data root: the embedded demo
(no ``--data-root``) is resolved one level above, by :func:`bop_cender.datasets.resolve_data_root`, so
that the data layer never imports the synthetic generator.
"""

from __future__ import annotations

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
) -> Dataset:
    """Open ``name``'s ``split`` under ``data_root``.

    Args:
        name: ``dimo``, ``tless`` or ``bop``.
        data_root: dataset root (see :func:`bop_cender.datasets.resolve_data_root` for the demo).
        split: split name; defaults per dataset (dimo: real, tless/bop: test).
        n_views: views per multi-view group for BOP-layout test splits (default 5, the paper's).
        seed: seed of the view grouping shuffle.
        model_type: BOP models folder variant (``cad``, ``eval``, ``reconst``; T-LESS default cad).

    Raises:
        ConfigError: unknown dataset name or split, or no data root.
        DatasetError: the data on disk is missing or inconsistent.
    """
    if name not in DATASETS:
        raise ConfigError(f"unknown dataset {name!r}; expected one of {', '.join(DATASETS)}", field="--dataset")
    split = split or DEFAULT_SPLIT[name]
    if data_root is None:
        raise ConfigError(f"--dataset {name} needs --data-root DIR", field="--data-root")
    root = Path(data_root)
    if name == "dimo":
        from bop_cender.data.dimo import open_dimo

        return open_dimo(root, split)
    if name == "tless":
        from bop_cender.data.tless import open_tless

        return open_tless(root, split, n_views=n_views, seed=seed, model_type=model_type)
    from bop_cender.data.bop import open_bop

    return open_bop(root, split, n_views=n_views, seed=seed, model_type=model_type)
