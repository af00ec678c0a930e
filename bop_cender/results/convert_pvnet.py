"""Convert PVNet-style pose outputs (3x4 ``[R | t]``, t in METRES) into a BOP results CSV (t in mm).

clean-pvnet (zju3dv) writes nothing in BOP form: its evaluator keeps, per image, a list of 3x4 camera-frame
poses from ``cv2.solvePnP`` with t in metres and no score (docs/datasets.md, "BOP results files"). Two
input forms are accepted:

1. A folder of ``.npy`` files, each holding one pose ``(3, 4)`` or several ``(N, 3, 4)`` of one object in
   one image, named either

   - ``{scene}_{im_id}_{obj_id}.npy`` (flat), e.g. ``000001_000042_000005.npy``, or
   - ``{scene}/{im_id}_{obj_id}.npy`` (a folder per scene), e.g. ``000001/000042_000005.npy``,

   where ``{scene}`` is the scene folder name (``000001``; DIMO ``000123_17``) and the ids are integers
   (zero-padded or not). Scores are 1.0 (PVNet has none), time -1 (unknown).
2. A JSON file mapping an image to its estimates::

       {"000001/000042": [{"obj_id": 5, "pose": [[r11, r12, r13, tx], [.., ty], [.., tz]],
                           "score": 0.93, "time": 0.21}, ...], ...}

   The key is ``{scene}/{im_id}``, or any path ending in ``{scene}/{folder}/{im_id}.{ext}`` (clean-pvnet's
   ``rgb_path``, e.g. ``test_primesense/000001/rgb/000042.png``). ``score`` defaults to 1.0 and ``time``
   (seconds for the whole image; all estimates of an image must agree) to -1.

Scene folder names become BOP int ids through :func:`bop_cender.data.scene_ids.scene_folder_to_int`.
Translations that cannot be in metres (millimetres given instead) are refused (:func:`check_units`).
"""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Callable, Collection, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bop_cender.data.bop_io import load_json
from bop_cender.data.scene_ids import scene_folder_to_int
from bop_cender.data.types import has_bool
from bop_cender.errors import ResultsError, ResultsWarning
from bop_cender.results.bop_csv import MAX_ID, TIME_TOLERANCE_S, BopEstimate, write_bop_results

METRES_TO_MM = 1000.0
_FLAT = re.compile(r"^(?P<scene>\d+(?:_\d{2})?)_(?P<im>\d+)_(?P<obj>\d+)$")
_IN_SCENE = re.compile(r"^(?P<im>\d+)_(?P<obj>\d+)$")
_IMAGE_FOLDERS = {"rgb", "gray", "depth", "images", "image"}
#: The fields of one estimate in the JSON form; any other (``Score``, ``scor``) is refused, not ignored.
ENTRY_FIELDS = ("obj_id", "pose", "score", "time")


def convert_pvnet(
    source: str | Path,
    out_csv: str | Path,
    known_obj_ids: Collection[int] | None = None,
    diameters: Mapping[int, float] | None = None,
    check: Callable[[list[BopEstimate]], None] | None = None,
) -> list[BopEstimate]:
    """Read PVNet-style outputs from ``source`` (a folder of ``.npy`` or a JSON file) and write a BOP CSV.

    Args:
        source: see the module docstring.
        out_csv: output path; must be a BOP result name (``pvnet_tless-test.csv``).
        known_obj_ids: if given, every obj_id must be one of these.
        diameters: model diameters (mm) by obj_id, if known: the unit check (:func:`check_units`) then
            measures distances in diameters, which holds for any camera set-up.
        check: called with the rows before anything is written (the CLI's: their scenes and images against the
            dataset the output's name says); raises to refuse them.

    Returns:
        The rows written (in mm).

    Raises:
        ResultsError: an unreadable or misnamed input, a pose of the wrong shape or not a rotation,
            an unknown object, translations that are not in metres, or an image whose estimates
            disagree on its time.
    """
    source = Path(source)
    if source.is_dir():
        rows = read_pvnet_folder(source)
    elif source.is_file():
        rows = read_pvnet_json(source)
    else:
        raise ResultsError("PVNet input not found (expected a folder of .npy files or a JSON file)", file=source)
    if known_obj_ids is not None:
        known = set(known_obj_ids)
        bad = sorted({r.obj_id for r in rows} - known)
        if bad:
            raise ResultsError(f"unknown object id(s) {bad}; known: {sorted(known)}", file=source, field="obj_id")
    if not rows:  # a header-only CSV that `score` would refuse later: say it now, and write nothing
        raise ResultsError("no estimates in it: nothing to convert", file=source)
    check_units(rows, source, diameters)
    if check is not None:
        check(rows)
    write_bop_results(out_csv, rows)
    return rows


#: Farther than this many diameters, an object is a few pixels wide at best: translations in millimetres
#: read as metres put it 1000 times farther (a 50 mm part at 0.8 m would be 16,000 diameters away).
MAX_DISTANCE_IN_DIAMETERS = 500.0
#: Without the models, a median camera distance above this (m) is taken for millimetres read as metres.
MAX_DISTANCE_M = 20.0


def check_units(rows: list[BopEstimate], source: Path, diameters: Mapping[int, float] | None = None) -> None:
    """Refuse translations that cannot be in metres (PVNet's unit), which would convert to parts kilometres away.

    A file written in millimetres converts without any other sign (the poses are valid rotations and finite
    numbers) and scores 0 everywhere. The median distance is judged, so that one wild estimate does
    not refuse a file: against the model diameters where they are known (objects farther than
    :data:`MAX_DISTANCE_IN_DIAMETERS` diameters), else against :data:`MAX_DISTANCE_M`.

    Raises:
        ResultsError: the median distance is implausible for metres.
    """
    if not rows:
        return
    distance_m = np.median([float(np.linalg.norm(r.t)) / METRES_TO_MM for r in rows])
    known = [r for r in rows if diameters and diameters.get(r.obj_id, 0) > 0]
    hint = "expected t in metres, as PVNet writes it; were they in millimetres? divide them by 1000"
    if known:
        in_diameters = float(np.median([np.linalg.norm(r.t) / diameters[r.obj_id] for r in known]))  # type: ignore[index]
        if in_diameters > MAX_DISTANCE_IN_DIAMETERS:
            raise ResultsError(
                f"implausible translations: the objects would lie a median {in_diameters:,.0f} model diameters"
                f" ({distance_m:,.0f} m) from the camera; {hint}",
                file=source,
                field="t",
            )
    elif distance_m > MAX_DISTANCE_M:
        raise ResultsError(
            f"implausible translations: the objects would lie a median {distance_m:,.0f} m from the camera; {hint}",
            file=source,
            field="t",
        )


def read_pvnet_folder(folder: str | Path) -> list[BopEstimate]:
    """Rows from a folder of ``.npy`` poses (flat names or a folder per scene), files in sorted order."""
    folder = Path(folder)
    rows: list[BopEstimate] = []
    files = sorted(p for p in folder.rglob("*.npy") if p.is_file())
    if not files:
        raise ResultsError("no .npy files found", file=folder)
    others = sorted(p for p in folder.rglob("*") if p.is_file() and p.suffix != ".npy" and not p.name.startswith("."))
    if others:  # an .npz or a .txt of poses would otherwise vanish from the results unsaid
        warnings.warn(
            f"{folder}: {len(others)} file(s) other than .npy not read (first: {others[0].relative_to(folder)})",
            ResultsWarning,
            stacklevel=2,
        )
    sources: dict[tuple[int, int, int], Path] = {}
    for path in files:
        rel = path.relative_to(folder)
        if len(rel.parts) == 1 and (m := _FLAT.match(path.stem)):
            scene = m["scene"]
        elif len(rel.parts) == 2 and (m := _IN_SCENE.match(path.stem)):
            scene = rel.parts[0]
        else:
            raise ResultsError(
                "expected {scene}_{im_id}_{obj_id}.npy or {scene}/{im_id}_{obj_id}.npy", file=path, field="file name"
            )
        scene_int = _scene(scene, path, "file name")
        key = (scene_int, int(m["im"]), int(m["obj"]))
        first = sources.setdefault(key, path)
        if first is not path:  # 000001_000000_000010.npy beside 1_0_10.npy, or a flat file beside a scene folder's
            raise ResultsError(
                f"scene {key[0]}, image {key[1]}, object {key[2]} again (first in {first}): one file per object and"
                " image, or its poses would be counted twice",
                file=path,
                field="file name",
            )
        try:
            poses = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError) as e:  # EOFError: an empty file
            raise ResultsError(f"cannot read .npy: {e}", file=path) from None
        for k, pose in enumerate(_poses(poses, path, "array")):
            rows.append(_row(scene_int, int(m["im"]), int(m["obj"]), 1.0, pose, -1.0, path, f"pose {k}"))
    return rows


def read_pvnet_json(path: str | Path) -> list[BopEstimate]:
    """Rows from a JSON mapping image keys to lists of ``{obj_id, pose, score?, time?}`` (in file order)."""
    path = Path(path)
    content = load_json(path, error=ResultsError)
    if not isinstance(content, dict):
        raise ResultsError(
            f"expected an object mapping image keys to estimates, got {type(content).__name__}", file=path
        )
    rows: list[BopEstimate] = []
    first_time: dict[tuple[int, int], tuple[float, str]] = {}  # per image, its first time (-1: unknown) and where
    keys: dict[tuple[int, int], str] = {}
    for key, entries in content.items():
        scene_int, im_id = _image_key(key, path)
        first = keys.setdefault((scene_int, im_id), key)
        if first != key:  # "000001/000000" beside "test_primesense/000001/rgb/000000.png"
            raise ResultsError(
                f"scene {scene_int}, image {im_id} again (first as {first!r}): one key per image, or its estimates"
                " would be counted twice",
                file=path,
                field=key,
            )
        if not isinstance(entries, list):
            raise ResultsError(f"expected a list of estimates, got {type(entries).__name__}", file=path, field=key)
        for i, entry in enumerate(entries):
            where = f"{key}[{i}]"
            if not isinstance(entry, dict) or "obj_id" not in entry or "pose" not in entry:
                raise ResultsError("expected an object with obj_id and pose (3x4, t in metres)", file=path, field=where)
            unknown = sorted(set(entry) - set(ENTRY_FIELDS))
            if unknown:
                raise ResultsError(
                    f"unknown field(s) {', '.join(map(repr, unknown))}; an estimate has {', '.join(ENTRY_FIELDS)}",
                    file=path,
                    field=where,
                )
            obj_id = _int(entry["obj_id"], path, f"{where}.obj_id")
            score = _number(entry.get("score", 1.0), path, f"{where}.score")
            time_s = _number(entry.get("time", -1.0), path, f"{where}.time")
            # checked here, so that the error names this file and key (the writer's: a row); unknown times (-1) too
            t0, at = first_time.setdefault((scene_int, im_id), (time_s, where))
            if abs(time_s - t0) > TIME_TOLERANCE_S:
                raise ResultsError(
                    f"time {_time_said(time_s)} differs from {_time_said(t0)} at {at} (the same image); one image's estimates"
                    f" must share its time within {TIME_TOLERANCE_S} s (the toolkit's rule, unknown times included)",
                    file=path,
                    field=f"{where}.time",
                )
            poses = _poses(entry["pose"], path, f"{where}.pose")
            if len(poses) != 1:
                raise ResultsError(f"expected one 3x4 pose, got {len(poses)}", file=path, field=f"{where}.pose")
            rows.append(_row(scene_int, im_id, obj_id, score, poses[0], time_s, path, where))
    return rows


def _time_said(t: float) -> str:
    """A time as a message shows it: ``0.5 s``, or ``-1.0 (unknown: ...)`` (an entry without one reads as -1)."""
    return f"{t!r} s" if t >= 0 else f"{t!r} (unknown: no time, or a negative one)"


def _image_key(key: str, path: Path) -> tuple[int, int]:
    """``{scene}/{im_id}`` or ``.../{scene}/{folder}/{im_id}.{ext}`` -> (scene int, im_id)."""
    parts = [p for p in re.split(r"[\\/]", key) if p]
    if parts:
        parts[-1] = parts[-1].split(".")[0]
    if len(parts) >= 3 and parts[-2] in _IMAGE_FOLDERS:
        parts = [*parts[:-2], parts[-1]]
    if len(parts) < 2 or not parts[-1].isdigit():
        raise ResultsError(
            "expected an image key {scene}/{im_id} or a path .../{scene}/rgb/{im_id}.png", file=path, field=key
        )
    return _scene(parts[-2], path, key), int(parts[-1])


def _scene(name: str, path: Path, field: str) -> int:
    try:
        return scene_folder_to_int(name)
    except ValueError as e:
        raise ResultsError(str(e), file=path, field=field) from None


def _poses(value: Any, path: Path, field: str) -> list[np.ndarray]:
    """``(3, 4)`` or ``(N, 3, 4)`` finite float64 poses (bools refused: NumPy would read them as 0 / 1)."""
    if isinstance(value, np.ndarray) and np.iscomplexobj(value):  # NumPy would drop the imaginary parts, warning
        raise ResultsError("expected real numbers in a 3x4 [R | t] pose, got complex ones", file=path, field=field)
    try:
        if has_bool(value):
            raise TypeError("a bool is not a number")
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ResultsError("expected numbers in a 3x4 [R | t] pose", file=path, field=field) from None
    if arr.shape == (3, 4):
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[1:] != (3, 4):
        raise ResultsError(f"expected a 3x4 pose or N x 3 x 4 poses, got shape {arr.shape}", file=path, field=field)
    if not np.all(np.isfinite(arr)):
        raise ResultsError("pose has NaN or inf", file=path, field=field)
    return list(arr)


def _row(
    scene: int, im: int, obj: int, score: float, pose: np.ndarray, time_s: float, path: Path, where: str
) -> BopEstimate:
    for name, value in (("scene_id", scene), ("im_id", im), ("obj_id", obj)):
        if value > MAX_ID:  # else a CSV is written that no reader takes back
            raise ResultsError(f"{name} {value} is too large (at most {MAX_ID})", file=path, field=where)
    R = pose[:, :3]
    if abs(np.linalg.det(R) - 1.0) > 1e-2 or np.abs(R @ R.T - np.eye(3)).max() > 1e-2:
        raise ResultsError("the 3x3 part of the pose is not a rotation", file=path, field=where)
    with np.errstate(over="ignore"):  # refused just below, in one error: no stray numpy warning before it
        t_mm = pose[:, 3] * METRES_TO_MM
    if not np.all(np.isfinite(t_mm)):  # e.g. 1e308 m: finite, but not in mm
        raise ResultsError(f"translation {pose[:, 3].tolist()} m is not finite in mm", file=path, field=f"{where}.pose")
    return BopEstimate(scene, im, obj, score, R, t_mm, time_s)


def _int(value: Any, path: Path, field: str) -> int:
    integral = isinstance(value, int) or (isinstance(value, float) and value.is_integer())  # not NaN / inf
    if isinstance(value, bool) or not integral or value < 0:
        raise ResultsError(f"expected a non-negative integer, got {value!r}", file=path, field=field)
    return int(value)


def _number(value: Any, path: Path, field: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ResultsError(f"expected a finite number, got {value!r}", file=path, field=field)
    return float(value)
