"""Load a BOP ``models*/`` folder: ``models_info.json`` plus ``obj_{id:06d}.ply`` per object."""

from __future__ import annotations

import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

from bop_cender.data.bop_io import as_number, load_json, require_keys
from bop_cender.data.types import ObjectModel
from bop_cender.errors import DatasetError, DatasetWarning
from bop_cender.geometry.symmetry import symmetries_from_model_info

_INFO_KEYS = ("diameter", "min_x", "min_y", "min_z", "size_x", "size_y", "size_z")
_POSITIVE_KEYS = ("diameter", "size_x", "size_y", "size_z")

EXTENT_TOLERANCE = 0.05
"""How far (a fraction of the longest side, and at least 1 mm) a mesh's bounding box may be from its
``models_info.json`` entry, and the entry's diameter from what its box allows, without a word (:func:`check_extent`,
:func:`check_diameter`). The toolkit computes both from the same mesh, so data it made agrees to rounding."""

SCALE_LIMIT = 2.0
"""Beyond this factor between a mesh's size and its entry's (or an entry's diameter and its box) the two are in other
units (a mesh or an entry in metres is off by 1,000, in centimetres by 10) and the model is refused; between
:data:`EXTENT_TOLERANCE` and this, a warning: a dataset of another maker whose entries are a little off is still
read (its scores use the entry's diameter, as the toolkit's do)."""


def _slack(size: np.ndarray) -> float:
    return max(EXTENT_TOLERANCE * float(np.max(size)), 1.0)


def _refuse_or_warn(gross: bool, message: str, file: Path | str, field: str) -> None:
    if gross:
        raise DatasetError(message, file=file, field=field)
    warnings.warn(f"{file}: {field}: {message}", DatasetWarning, stacklevel=3)


def check_diameter(diameter: float, size: np.ndarray, info_path: Path, where: str) -> None:
    """An entry's ``diameter`` (the largest distance between two vertices) must lie between its bounding box's longest
    side and its diagonal (``size (3,)``, mm): within :data:`EXTENT_TOLERANCE`, silently; within
    :data:`SCALE_LIMIT`, with a warning; else refused. Every MSSD threshold is a fraction of the diameter, so one in
    other units than the box scores every pose right or none."""
    size = np.asarray(size, dtype=np.float64)
    longest, diagonal = float(size.max()), float(np.linalg.norm(size))
    if longest - _slack(size) <= diameter <= diagonal + _slack(size):
        return
    _refuse_or_warn(
        not longest / SCALE_LIMIT <= diameter <= diagonal * SCALE_LIMIT,
        f"diameter {diameter:g} mm does not fit its bounding box {' x '.join(f'{x:g}' for x in size)} mm (a diameter"
        f" lies between the longest side, {longest:g}, and the diagonal, {diagonal:.4g}): an entry in other units?",
        info_path,
        f"{where}.diameter",
    )


def check_extent(model: ObjectModel, vertices: np.ndarray) -> None:
    """A mesh's bounding box must be its ``models_info.json`` entry's (``min_*``, ``size_*``): within
    :data:`EXTENT_TOLERANCE`, silently; each side within :data:`SCALE_LIMIT` of the entry's and the box shifted by
    at most its longest side, with a warning; else refused (other units, other axes, another origin: the entry's
    box centre, the method's object centre, would be off the part). A mesh in metres scored with a millimetre entry
    made every MSSD and MSPD tiny, so that wrong poses scored AR 1.0 (and the renderer drew parts 1,000 times too
    small)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    lo, hi = vertices.min(0), vertices.max(0)
    slack = _slack(model.bbox_size)
    if np.abs(hi - lo - model.bbox_size).max() <= slack and np.abs(lo - model.bbox_min).max() <= slack:
        return
    info = Path(model.source).name if model.source else "models_info.json"

    def box(low: np.ndarray, size: np.ndarray) -> str:
        return f"min {', '.join(f'{x:.4g}' for x in low)}, size {' x '.join(f'{x:.4g}' for x in size)}"

    size = hi - lo
    scales = size / model.bbox_size  # per side: other units, or other axes (20 x 40 x 100 for an entry's 100 x 40 x 20)
    off_scale = (np.abs(size - model.bbox_size) > slack) & ((scales < 1.0 / SCALE_LIMIT) | (scales > SCALE_LIMIT))
    shifted = float(np.abs(lo - model.bbox_min).max()) > float(model.bbox_size.max())  # its box centre off the part
    _refuse_or_warn(
        bool(off_scale.any()) or shifted,
        f"the mesh's bounding box ({box(lo, hi - lo)}) is not the one {info} gives object {model.obj_id}"
        f" ({box(model.bbox_min, model.bbox_size)}, mm): a mesh in other units, axes or origin than its entry?",
        model.path,
        f"{info} {model.obj_id}: min_x..size_z",
    )


def model_path(models_dir: Path, obj_id: int) -> Path:
    """``models_dir/obj_{obj_id:06d}.ply``."""
    return Path(models_dir) / f"obj_{obj_id:06d}.ply"


def load_models(
    models_dir: str | Path,
    is_target: Callable[[int], bool] = lambda obj_id: True,
) -> dict[int, ObjectModel]:
    """Read ``models_info.json`` of a models folder into :class:`ObjectModel` s (meshes lazy).

    Args:
        models_dir: folder with ``models_info.json`` and the PLY files.
        is_target: which ids are pose targets (DIMO: ids < 100); the others are occluders.

    Raises:
        DatasetError: missing folder/file (a listed model's PLY included), malformed JSON, a missing key or a bad value.
    """
    models_dir = Path(models_dir)
    info_path = models_dir / "models_info.json"
    if not models_dir.is_dir():
        raise DatasetError("models folder not found", file=models_dir)
    info = load_json(info_path, keys_to_int=True)
    if not isinstance(info, dict) or not info:
        raise DatasetError("expected a non-empty object keyed by object id", file=info_path)
    models: dict[int, ObjectModel] = {}
    for key, entry in info.items():
        if not isinstance(key, int):
            raise DatasetError(f"object id keys must be integers, got {key!r}", file=info_path, field=str(key))
        where = f"{key}"
        require_keys(entry, _INFO_KEYS, info_path, where)
        vals = {k: as_number(entry[k], info_path, f"{where}.{k}") for k in _INFO_KEYS}
        for k in _POSITIVE_KEYS:  # a negative size or diameter: every threshold and centre derived from it is wrong
            if vals[k] <= 0:
                raise DatasetError(
                    f"expected a positive number (mm), got {entry[k]!r}", file=info_path, field=f"{where}.{k}"
                )
        check_diameter(vals["diameter"], np.array([vals[k] for k in ("size_x", "size_y", "size_z")]), info_path, where)
        try:
            discrete, continuous = symmetries_from_model_info(entry)
        except ValueError as e:
            raise DatasetError(str(e), file=info_path, field=where) from None
        path = model_path(models_dir, key)
        if not path.is_file():  # checked now (cheap); the mesh loads later
            raise DatasetError(f"model of object {key} listed in models_info.json is missing", file=path)
        models[key] = ObjectModel(
            obj_id=key,
            path=path,
            diameter=vals["diameter"],
            bbox_min=[vals["min_x"], vals["min_y"], vals["min_z"]],
            bbox_size=[vals["size_x"], vals["size_y"], vals["size_z"]],
            symmetries_discrete=discrete,
            symmetries_continuous=continuous,
            is_target=bool(is_target(key)),
            source=str(info_path),
        )
    return dict(sorted(models.items()))
