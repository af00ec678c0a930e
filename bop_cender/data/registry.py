"""Open a dataset split: one request value, one function.

:class:`DatasetRequest` names what to open (``dimo``, ``tless``, ``bop`` or any BOP dataset name, its root,
split and loader settings); :func:`open_dataset` opens it. This is the single entry point the CLI, the
scorer and the runner use. It needs a data root: the embedded demo (no ``--data-root``) is resolved one
level above, by :func:`bop_cender.datasets.resolve_data_root`, so that the data layer never imports the
synthetic generator.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass
from pathlib import Path

from bop_cender.data.layout import SYNTH_RECORD
from bop_cender.data.types import Dataset
from bop_cender.errors import ConfigError, DatasetWarning

#: The names the command line offers; any other BOP dataset name opens with the generic BOP loader. The
#: BOP-Industrial names (``bop_cender.data.industrial_params.INDUSTRIAL``) open their multi-sensor splits with
#: :func:`bop_cender.data.industrial.open_industrial`, their classic-layout ones (``train_pbr``) as any BOP split.
DATASETS = ("dimo", "tless", "bop", "ipd", "xyzibd", "itoddmv")
DEFAULT_SPLIT = {"dimo": "real", "tless": "test", "bop": "test"}


@dataclass(frozen=True)
class DatasetRequest:
    """Which dataset split to open, and how.

    Attributes:
        dataset: ``dimo``, ``tless``, ``bop`` (a BOP-layout folder, named after it) or a BOP dataset name
            (``lmo``, ``itodd``: the generic BOP loader under that name; ``ipd``, ``xyzibd``, ``itoddmv``: the
            multi-sensor reader where the split folder is in that layout). ``bop`` opens a multi-sensor split
            folder with the multi-sensor reader too.
        root: dataset root folder; None = not given (see :func:`bop_cender.datasets.resolve_data_root`).
        split: split name; None = the dataset's default (dimo: real, others: test).
        n_views: views per multi-view group of BOP-layout test splits (default 5, the paper's).
        seed: seed of the view-grouping shuffle.
        model_type: BOP models folder variant (``cad``, ``eval``, ``reconst``; T-LESS default cad).
        split_type: BOP split type (``primesense``, ``kinect``), as result file names carry it.
    """

    dataset: str
    root: Path | None = None
    split: str | None = None
    n_views: int | None = None
    seed: int = 0
    model_type: str | None = None
    split_type: str | None = None

    def __post_init__(self) -> None:
        if self.root is not None:
            object.__setattr__(self, "root", Path(self.root))

    @property
    def loader(self) -> str:
        """``dimo``, ``tless`` or ``bop`` (the generic BOP loader)."""
        return self.dataset if self.dataset in ("dimo", "tless") else "bop"

    @property
    def split_name(self) -> str:
        """The split the opened Dataset will be named by: the default one where none is given, T-LESS
        ``test`` with another sensor than primesense as ``test_{split_type}``."""
        split = self.split or DEFAULT_SPLIT[self.loader]
        if self.loader == "tless" and split == "test" and self.split_type not in (None, "primesense"):
            split = f"test_{self.split_type}"
        return split


def open_dataset(request: DatasetRequest) -> Dataset:
    """Open the split ``request`` names.

    Raises:
        ConfigError: unknown split, split type or model type, or no data root.
        DatasetError: the data on disk is missing or inconsistent.
    """
    loader = request.loader
    split = request.split_name
    if request.root is None:
        raise ConfigError(f"--dataset {request.dataset} needs --data-root DIR", field="--data-root")
    root = request.root
    if root.exists() and not root.is_dir():  # said here, where the option is known, not as a missing folder
        raise ConfigError("is a file, expected the dataset root folder", file=root, field="--data-root")
    _warn_if_unfinished(root)
    if loader == "dimo":
        from bop_cender.data.dimo import open_dimo

        _refuse_bop_only_options(request)
        return open_dimo(root, split)
    if loader == "tless":
        from bop_cender.data.tless import open_tless

        return open_tless(root, split, n_views=request.n_views, seed=request.seed, model_type=request.model_type)
    from bop_cender.data.industrial import multi_sensor_folder, open_industrial

    folder = multi_sensor_folder(root, split, request.split_type)
    if folder is not None:
        if request.n_views is not None:
            raise ConfigError(
                f"a multi-sensor scene is the sensors' images of one capture, not groups of --n-views {request.n_views}"
                " images; --n-views is for single-sensor BOP test splits",
                field="--n-views",
            )
        return open_industrial(
            root, split, name=None if request.dataset == "bop" else request.dataset, folder=folder,
            model_type=request.model_type,
        )  # fmt: skip
    from bop_cender.data.bop import open_bop

    return open_bop(
        root, split, name=None if request.dataset == "bop" else request.dataset, n_views=request.n_views,
        seed=request.seed, model_type=request.model_type, split_type=request.split_type,
    )  # fmt: skip


def _refuse_bop_only_options(request: DatasetRequest) -> None:
    """DIMO has one models folder and its multi-view scenes are its folders' viewpoints: ``--model-type`` and
    ``--n-views`` would be ignored there, and an ignored option is a run the user did not ask for.

    Raises:
        ConfigError: either is given (``field``: the option).
    """
    if request.model_type is not None:
        raise ConfigError(
            f"DIMO has one models folder (models/); --model-type {request.model_type} is for BOP layouts",
            field="--model-type",
        )
    if request.n_views is not None:
        raise ConfigError(
            f"a DIMO scene is the viewpoints of its folder, not groups of --n-views {request.n_views} images; "
            "--n-views is for BOP-layout test splits",
            field="--n-views",
        )


def _warn_if_unfinished(root: Path) -> None:
    """A warning where ``root`` is a dataset ``bop-cender synth`` has not finished (its record says ``complete``
    false: killed midway, or still running): its scene folders read as the whole dataset otherwise. Real data has no
    record; records of before the field say nothing."""
    path = root / SYNTH_RECORD
    if not path.is_file():
        return
    try:
        complete = json.loads(path.read_text()).get("complete")
    except (OSError, ValueError, AttributeError):
        return  # synth itself refuses a broken record; reading the data does not need it
    if complete is False:
        warnings.warn(
            f"{path}: complete: bop-cender synth has not finished this dataset (interrupted, or still running): it"
            " holds only the scenes written so far; rerun the same synth command to complete it",
            DatasetWarning,
            stacklevel=3,
        )
