"""T-LESS in the BOP layout: the generic BOP loader with T-LESS's folders, camera files and sizes.

T-LESS specifics, all as data below (``bop_toolkit_lib/dataset_params.py`` and
docs/datasets.md, "T-LESS and other BOP datasets"):

- split ``test`` is ``test_primesense/``, ``train`` is ``train_primesense/`` (400x400 crops),
  ``train_pbr`` is ``train_pbr/`` (JPEG); literal folder names are accepted too;
- the models are ``models_cad/`` by default (``reconst`` and ``eval`` selectable), evaluation
  uses ``models_eval/``;
- ``camera_primesense.json`` describes the 720x540 test and PBR images, not the training crops.

Multi-view grouping, BOP'19 target selection and all checks are :func:`open_bop_split`'s.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from bop_cender.data.bop import EVAL_MODELS_DIR, SplitLayout, open_bop_split
from bop_cender.data.types import Dataset
from bop_cender.errors import ConfigError

NAME = "tless"
DEFAULT_MODEL_TYPE = "cad"
MODEL_TYPES = ("cad", "reconst", "eval")


@dataclass(frozen=True)
class TlessSplit:
    """One T-LESS split folder's constants.

    Attributes:
        folder: split folder under the root.
        image_size: ``(width, height)`` of its images (dataset_params.py).
        camera_file: root camera file that describes these images, None when none does.
    """

    folder: str
    image_size: tuple[int, int]
    camera_file: str | None


#: Split name -> folder and constants. A split may also be named by its folder.
SPLITS: dict[str, TlessSplit] = {
    "test": TlessSplit("test_primesense", (720, 540), "camera_primesense.json"),
    "train_pbr": TlessSplit("train_pbr", (720, 540), "camera_primesense.json"),
    "train": TlessSplit("train_primesense", (400, 400), None),
    "test_kinect": TlessSplit("test_kinect", (720, 540), "camera_kinect.json"),
    "test_canon": TlessSplit("test_canon", (2560, 1920), "camera_canon.json"),
    "train_kinect": TlessSplit("train_kinect", (400, 400), None),
    "train_canon": TlessSplit("train_canon", (1900, 1900), None),
    "train_render_reconst": TlessSplit("train_render_reconst", (1280, 1024), None),
}


def open_tless(
    root: str | Path,
    split: str,
    *,
    n_views: int | None = None,
    seed: int = 0,
    model_type: str | None = None,
) -> Dataset:
    """Open a T-LESS split (``test``, ``train_pbr``, ``train`` or a split folder name).

    Args:
        root: the ``tless/`` folder.
        split: split name; ``test`` -> ``test_primesense/``.
        n_views: views per multi-view group (default 5, the paper's).
        seed: seed of the view-grouping shuffle.
        model_type: ``cad`` (default, ``models_cad/``), ``reconst`` or ``eval``.

    Raises:
        ConfigError: unknown split or model type.
        DatasetError: missing or inconsistent files.
    """
    spec = tless_split(split)
    model_type = model_type or DEFAULT_MODEL_TYPE
    if model_type not in MODEL_TYPES:
        raise ConfigError(
            f"unknown T-LESS model type {model_type!r}; expected one of {', '.join(MODEL_TYPES)}", field="--model-type"
        )
    layout = SplitLayout(
        folder=spec.folder,
        camera_file=spec.camera_file,
        image_size=spec.image_size,
        models_dir=f"models_{model_type}",
        eval_models_dir=EVAL_MODELS_DIR,
    )
    return open_bop_split(root, NAME, split, layout, n_views=n_views, seed=seed)


def tless_split(split: str) -> TlessSplit:
    """The constants of a T-LESS split named by the user (``test``) or by its folder (``test_primesense``)."""
    if split in SPLITS:
        return SPLITS[split]
    for spec in SPLITS.values():
        if spec.folder == split:
            return spec
    raise ConfigError(f"unknown T-LESS split {split!r}; expected one of {', '.join(SPLITS)}", field="--split")
