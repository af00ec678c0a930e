"""BOP results CSV: world-frame estimates to per-image rows, a strict reader, an exact writer.

The format (BOP'19, ``docs/bop_challenge_2019.md``; ``inout.load_bop_results``) is one line per
estimate, ``scene_id,im_id,obj_id,score,R,t,time``: ``R`` 9 numbers row-major (model to camera),
``t`` 3 numbers in mm, ``time`` seconds for the whole image (``-1`` = unknown), an optional header
on line 1. File names are ``{method}_{dataset}-{split}[-{split_type}][_{optional_id}].csv``.

The reader accepts every file the official toolkit accepts that is also sane (real submissions
unchanged: no final newline, CRLF, trailing blank lines) and checks every row, reporting all bad
lines at once; the writer applies the same checks before writing, writes floats with ``repr`` so
that a write/read round trip is exact in float64, and writes atomically.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Collection, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bop_cender.data.bop_io import atomic_path, read_text
from bop_cender.data.scene_ids import scene_folder_to_int
from bop_cender.data.types import ROTATION_TOLERANCE, Scene
from bop_cender.errors import ResultsError, ResultsWarning
from bop_cender.estimates import SceneEstimate
from bop_cender.geometry.poses import compose, make_pose
from bop_cender.geometry.rotations import orthonormality_error
from bop_cender.results.files import (  # noqa: F401  (re-exported: one import site for users)
    ResultName,
    parse_result_filename,
    read_run_sidecar,
    result_filename,
    sidecar_path,
    write_run_sidecar,
)

HEADER = "scene_id,im_id,obj_id,score,R,t,time"
#: Above this (max |R R^T - I|) a rotation is accepted with a ResultsWarning; above
#: ROTATION_TOLERANCE (1e-2) or with det < 0 it is an error. Rotations are never re-orthonormalised.
ROTATION_WARN_TOLERANCE = 1e-4
#: The largest id the reader takes (18 digits: every such id fits in int64).
MAX_ID = 10**18 - 1
#: All estimates of one image must share their time within this (toolkit's check_consistent_timings).
TIME_TOLERANCE_S = 0.001


@dataclass(frozen=True, eq=False)
class BopEstimate:
    """One row of a BOP results CSV: a pose in one image's camera frame.

    Attributes:
        scene_id: int scene id (DIMO ``000123_17`` -> 12317, see :mod:`bop_cender.data.scene_ids`).
        im_id: image id. obj_id: object id.
        score: confidence, higher is better.
        R: ``(3, 3)`` float64 model-to-camera rotation (read-only).
        t: ``(3,)`` float64 model-to-camera translation, mm (read-only).
        time: seconds for the whole image; negative = unknown.
        line: line number in the file this row was read from (1-based), None if not read.

    Equality compares every value bit for bit and ignores ``line`` (where a row came from).
    """

    scene_id: int
    im_id: int
    obj_id: int
    score: float
    R: np.ndarray
    t: np.ndarray
    time: float
    line: int | None = None

    def __post_init__(self) -> None:
        for name in ("scene_id", "im_id", "obj_id"):
            object.__setattr__(self, name, int(getattr(self, name)))
        object.__setattr__(self, "score", float(self.score))
        object.__setattr__(self, "time", float(self.time))
        for name, shape in (("R", (3, 3)), ("t", (3,))):
            arr = getattr(self, name)
            if (
                isinstance(arr, np.ndarray)
                and arr.dtype == np.float64
                and arr.shape == shape
                and not arr.flags.writeable
            ):
                continue  # already read-only (the reader's rows share its arrays): no copy
            arr = np.array(arr, dtype=np.float64)  # a private copy, so the caller's array stays theirs
            if arr.size != math.prod(shape):
                raise ValueError(f"BopEstimate.{name}: expected {math.prod(shape)} numbers, got shape {arr.shape}")
            arr = arr.reshape(shape)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, BopEstimate):
            return NotImplemented
        return (
            (self.scene_id, self.im_id, self.obj_id, self.score, self.time)
            == (other.scene_id, other.im_id, other.obj_id, other.score, other.time)
            and np.array_equal(self.R, other.R)
            and np.array_equal(self.t, other.t)
        )

    __hash__ = None  # type: ignore[assignment]

    @property
    def T_cam_model(self) -> np.ndarray:
        """``(4, 4)`` model-to-camera transform, mm."""
        return make_pose(self.R, self.t)


def scene_estimates_to_rows(scene: Scene, estimate: SceneEstimate) -> list[BopEstimate]:
    """Per-image camera-frame rows for every (view, object) of a scene: ``T_cam_model = T_cam_world @ T_world_model``.

    Every object is written into every evaluated view of the scene (as CosyPose's multi-view results are; a
    multi-sensor scene's other sensors are views of the method, not BOP images: :attr:`Scene.evaluated_views`);
    BOP's evaluation only looks at the targets of each image, so an object outside one view costs
    nothing. ``time`` of every row is the scene's ``time_s``: a multi-view method produces no
    image's estimates before the whole scene is processed, so each image waited that long (dividing
    by the view count would understate the latency of a single image; the runner passes the split it
    wants). Each row's score is the object's confidence in that image (:meth:`ObjectEstimate.score_in`).

    Returns:
        ``len(scene.evaluated_views) * len(estimate.objects)`` rows, view by view, objects in estimate order.
    """
    if estimate.scene_key != scene.key or estimate.scene_id != scene.scene_id:
        raise ValueError(f"estimate for scene {estimate.scene_key!r} given with scene {scene.key!r}")
    scene_id = scene_folder_to_int(scene.scene_id)
    rows = []
    for view in scene.evaluated_views:
        for obj in estimate.objects:
            T = compose(view.T_cam_world, obj.T_world_model)
            score = obj.score_in(view.im_id)
            rows.append(BopEstimate(scene_id, view.im_id, obj.obj_id, score, T[:3, :3], T[:3, 3], estimate.time_s))
    return rows


def write_bop_results(
    path: str | Path, rows: Iterable[BopEstimate], *, sort: bool = True, strict_name: bool = True
) -> None:
    """Write rows as a BOP results CSV, atomically (a failure leaves any previous file untouched).

    Floats are written with ``repr`` (shortest string that reads back to the same float64), so
    :func:`read_bop_results` returns the rows bit for bit. With ``sort`` (default) rows are ordered
    by ``(scene_id, im_id, score descending)``, ties in the given order, so the file does not depend
    on the order in which scenes finished; ``sort=False`` keeps the given order.

    Raises:
        ResultsError: the file name is not a valid BOP result name (``strict_name``), or rows fail
            the reader's checks (every bad row listed by its 0-based index in the given order).
    """
    path = Path(path)
    if strict_name:
        parse_result_filename(path.name)
        if path.suffix != ".csv":
            raise ResultsError(f"expected the suffix .csv, got {path.suffix!r}", file=path, field="file name")
    rows = list(rows)
    problems, warn = _check_arrays(_rows_to_arrays(rows), np.arange(len(rows)), "row", known_obj_ids=None)
    if problems:
        raise ResultsError(
            f"{len(problems)} problem(s) in the rows to write", file=path, problems=_fmt(problems, "row")
        )
    _warn_rotations(warn, path, "row")
    if sort:
        rows = sorted(rows, key=lambda r: (r.scene_id, r.im_id, -r.score))
    with atomic_path(path) as tmp, tmp.open("w", encoding="utf-8", newline="\n") as f:
        f.write(HEADER + "\n")
        for row in rows:
            f.write(_format_row(row) + "\n")


def _format_row(row: BopEstimate) -> str:
    R = " ".join(map(repr, row.R.ravel().tolist()))
    t = " ".join(map(repr, row.t.tolist()))
    return f"{row.scene_id},{row.im_id},{row.obj_id},{row.score!r},{R},{t},{row.time!r}"


def read_bop_results(
    path: str | Path, known_obj_ids: Collection[int] | None = None, check_times: bool = True
) -> list[BopEstimate]:
    """Read and check a BOP results CSV; every bad line is reported, with its number, in one error.

    Accepted as the toolkit accepts it: a header only on line 1 (any line containing the header
    text), CRLF or LF, no final newline; trailing blank lines are also tolerated. Checked on every
    row: 7 columns; ids non-negative ints; score, R, t, time finite numbers; R 9 numbers, t 3;
    R a rotation (error when max|R R^T - I| > 1e-2 or det < 0, one :class:`ResultsWarning` for
    all rows above 1e-4; never re-orthonormalised); obj_id in ``known_obj_ids`` when given; all
    rows of one image with known times within 0.001 s of each other (the toolkit's rule; ``check_times`` False
    leaves it to the caller: BOP'24 checks it on the rows its per-image cap keeps, as the toolkit does).

    Returns:
        The rows in file order, each with its ``line``.

    Raises:
        ResultsError: missing/unreadable file, or any bad row (``problems`` lists them all).
    """
    path = Path(path)
    text = read_text(path, ResultsError, "results file")
    lines = text.split("\n")  # read_text already turned CRLF (and lone CR) into LF, as the toolkit's open()
    end = len(lines)
    while end and not lines[end - 1].strip():
        end -= 1
    problems: list[tuple[int, str]] = []
    parsed: list[tuple] = []
    if end and HEADER not in lines[0] and _looks_like_a_header(lines[0]):  # one line, not one error per row
        raise ResultsError(
            f"expected the header '{HEADER}' (or none), got {lines[0].strip()!r}: the columns are read in that order",
            file=path,
            field="line 1",
        )
    for i in range(1 if lines and HEADER in lines[0] else 0, end):
        row = _parse_line(lines[i], i + 1, problems)
        if row is not None:
            parsed.append(row)
    if parsed:
        numbers, sid, im, obj, score, R, t, time = (np.array(c) for c in zip(*parsed, strict=True))
        R = R.reshape(-1, 3, 3)
        R.setflags(write=False)  # rows below share these read-only arrays instead of copying them
        t.setflags(write=False)
    else:
        numbers, sid, im, obj, score, R, t, time = _empty_arrays()
    more, warn = _check_arrays((sid, im, obj, score, R, t, time), numbers, "line", known_obj_ids, check_times)
    problems = sorted(problems + more, key=lambda p: p[0])  # stable: a line's problems stay in column order
    if problems:
        bad = len({n for n, _ in problems})
        raise ResultsError(
            f"{bad} bad line(s) in BOP results (expected '{HEADER}')", file=path, problems=_fmt(problems, "line")
        )
    _warn_rotations(warn, path, "line")
    _warn_repeats(np.column_stack([sid, im, obj, R.reshape(-1, 9), t]).astype(np.float64), numbers, path)
    return [
        BopEstimate(int(sid[k]), int(im[k]), int(obj[k]), float(score[k]), R[k], t[k], float(time[k]), int(numbers[k]))
        for k in range(len(parsed))
    ]


_NUMBER_FIELDS = (("score", 3, 1), ("R", 4, 9), ("t", 5, 3), ("time", 6, 1))  # name, column, count


def _parse_line(line: str, number: int, problems: list[tuple[int, str]]) -> tuple | None:
    """One CSV line to ``(number, scene_id, im_id, obj_id, score, R[9], t[3], time)``; None on a problem."""
    fields = line.split(",")
    if len(fields) != 7:
        what = "an empty line" if not line.strip() else str(len(fields))
        problems.append((number, f"expected 7 comma-separated fields, got {what}"))
        return None
    ok = True
    ids = []
    for name, value in zip(("scene_id", "im_id", "obj_id"), fields[:3], strict=False):
        s = value.strip()
        if s.isascii() and s.isdigit() and len(s) <= 18:  # fits int64
            ids.append(int(s))
        else:
            problems.append((number, f"{name}: expected a non-negative integer, got {value!r}"))
            ok = False
    numbers = []
    for name, column, count in _NUMBER_FIELDS:
        value = fields[column]
        tokens = value.split()
        if len(tokens) != count:
            problems.append((number, f"{name}: expected {count} number(s), got {len(tokens)}"))
            ok = False
            continue
        try:
            numbers.append(list(map(float, tokens)))
        except ValueError:
            problems.append((number, f"{name}: expected number(s), got {value.strip()!r}"))
            ok = False
    if not ok:
        return None
    return (number, *ids, numbers[0][0], numbers[1], numbers[2], numbers[3][0])


def _empty_arrays() -> tuple[np.ndarray, ...]:
    i = np.zeros(0, dtype=np.int64)
    f = np.zeros(0)
    return i, i, i, i, f, np.zeros((0, 3, 3)), np.zeros((0, 3)), f


def _rows_to_arrays(rows: list[BopEstimate]) -> tuple[np.ndarray, ...]:
    if not rows:
        return _empty_arrays()[1:]
    cols = list(zip(*((r.scene_id, r.im_id, r.obj_id, r.score, r.R, r.t, r.time) for r in rows), strict=True))
    return tuple(np.array(c) for c in cols)  # (N,) ids, score, (N, 3, 3) R, (N, 3) t, time


def _check_arrays(
    cols: tuple[np.ndarray, ...],
    numbers: np.ndarray,
    word: str,
    known_obj_ids: Collection[int] | None,
    check_times: bool = True,
) -> tuple[list[tuple[int, str]], tuple[int, int, float] | None]:
    """Row checks shared by reader and writer, vectorised over N rows.

    Args:
        cols: ``(scene_id, im_id, obj_id)`` ``(N,)`` ints, score ``(N,)``, R ``(N, 3, 3)``,
            t ``(N, 3)``, time ``(N,)``.
        numbers: ``(N,)`` the line (reader) or row index (writer) each row is reported under.
        word: ``line`` or ``row``, for messages that refer to another row.

    Returns:
        ``(problems, warn)``: problems as ``(number, message)``; warn is ``(count, worst number,
        worst error)`` of rotations above ROTATION_WARN_TOLERANCE but accepted, or None.
    """
    sid, im, obj, score, R, t, time = cols
    problems: list[tuple[int, str]] = []
    for name, ids in (("scene_id", sid), ("im_id", im), ("obj_id", obj)):
        for k in np.flatnonzero(ids < 0):
            problems.append((int(numbers[k]), f"{name}: expected a non-negative integer, got {ids[k]}"))
    finite_R = np.isfinite(R).all(axis=(1, 2))
    finite = {"score": np.isfinite(score), "R": finite_R, "t": np.isfinite(t).all(axis=1), "time": np.isfinite(time)}
    for name, ok in finite.items():
        for k in np.flatnonzero(~ok):
            problems.append((int(numbers[k]), f"{name}: expected finite numbers, found NaN or inf"))
    err = np.full(len(R), np.nan)
    det = np.full(len(R), np.nan)
    err[finite_R] = orthonormality_error(R[finite_R])
    det[finite_R] = np.linalg.det(R[finite_R])
    for k in np.flatnonzero(finite_R & ((err > ROTATION_TOLERANCE) | (det < 0))):
        msg = f"R: not a rotation (max |R R^T - I| = {err[k]:.3g}, det = {det[k]:.4f};"
        problems.append((int(numbers[k]), msg + f" expected <= {ROTATION_TOLERANCE:g} and det +1)"))
    if known_obj_ids is not None:
        known = {int(i) for i in known_obj_ids}
        for k in np.flatnonzero(~np.isin(obj, list(known))):
            problems.append((int(numbers[k]), f"obj_id: unknown object {obj[k]} (known: {sorted(known)})"))
    if check_times:
        problems += _check_times(sid, im, time, numbers, word)
    soft = finite_R & (err > ROTATION_WARN_TOLERANCE) & (err <= ROTATION_TOLERANCE) & (det >= 0)
    warn = None
    if soft.any():
        worst = int(np.nanargmax(np.where(soft, err, np.nan)))
        warn = (int(soft.sum()), int(numbers[worst]), float(err[worst]))
    problems.sort(key=lambda p: p[0])
    return problems, warn


def _check_times(
    sid: np.ndarray, im: np.ndarray, time: np.ndarray, numbers: np.ndarray, word: str
) -> list[tuple[int, str]]:
    """Per image, every known time within TIME_TOLERANCE_S of that image's first known time: the toolkit's
    ``check_consistent_timings`` (thodan/bop_toolkit @ cea62d6) skips unknown (negative) times, so a -1 beside 0.5 in
    one image passes it (and makes the average time unknown)."""
    first: dict[tuple[int, int], int] = {}
    problems = []
    times = time.tolist()
    for k, (s, i, tm) in enumerate(zip(sid.tolist(), im.tolist(), times, strict=True)):
        if tm != tm or tm < 0:  # NaN: reported elsewhere; negative: unknown, not compared
            continue
        j = first.setdefault((s, i), k)
        if abs(tm - times[j]) > TIME_TOLERANCE_S:
            msg = f"time: {tm!r} s differs from {times[j]!r} s of the same image (scene {s}, image {i}) at {word} {numbers[j]}"
            problems.append(
                (int(numbers[k]), msg + f"; one image's estimates must share its time within {TIME_TOLERANCE_S} s")
            )
    return problems


def check_row_times(rows: list[BopEstimate], path: str | Path) -> None:
    """The reader's time check on rows read with ``check_times=False`` (BOP'19 checks every row, BOP'24 the rows its
    per-image cap keeps, as the toolkit does).

    Raises:
        ResultsError: known times of one image more than 0.001 s apart (every such line listed).
    """
    if not rows:
        return
    cols = [np.array(c) for c in zip(*((r.scene_id, r.im_id, r.time, r.line or 0) for r in rows), strict=True)]
    problems = sorted(_check_times(cols[0], cols[1], cols[2], cols[3], "line"))
    if problems:
        raise ResultsError(
            f"{len(problems)} line(s) with another time than their image's", file=path, problems=_fmt(problems, "line")
        )


def _fmt(problems: list[tuple[int, str]], word: str) -> list[str]:
    return [f"{word} {n}: {msg}" for n, msg in problems]


def _looks_like_a_header(line: str) -> bool:
    """Whether a first line that is not the header is a header of other columns, case or spacing (``scene_id, im_id,
    ...``, ``SCENE_ID,...``, columns in another order): no field of it is a number."""
    fields = [f.strip() for f in line.replace(";", ",").split(",") if f.strip()]
    return bool(fields) and not any(_is_number(f.split()[0]) for f in fields)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _warn_rotations(warn: tuple[int, int, float] | None, path: Path, word: str) -> None:
    if warn is not None:
        count, worst, err = warn
        warnings.warn(
            f"{path}: {count} rotation(s) slightly non-orthonormal (max |R R^T - I| > {ROTATION_WARN_TOLERANCE:g});"
            f" worst {err:.3g} at {word} {worst}; used as they are",
            ResultsWarning,
            stacklevel=3,
        )


def _warn_repeats(keys: np.ndarray, numbers: np.ndarray, path: Path) -> None:
    """One :class:`ResultsWarning` when rows repeat an earlier row's image, object and pose exactly (``keys``
    ``(N, 15)``: scene, image, object, R, t): a file written twice, or two methods' rows merged. They are
    scored as the toolkit scores them (each an estimate), but the user should hear of it."""
    if len(keys) < 2:
        return
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    original = first[inverse.reshape(-1)]  # per row, the first row with its keys
    repeats = np.flatnonzero(original != np.arange(len(keys)))
    if repeats.size:
        k = int(repeats[0])
        warnings.warn(
            f"{path}: {repeats.size} row(s) repeat an earlier row's image, object and pose (first: line"
            f" {numbers[k]} repeats line {numbers[original[k]]}); each is scored as an estimate,"
            " as the toolkit scores them",
            ResultsWarning,
            stacklevel=3,
        )


def group_by_image(rows: Iterable[BopEstimate]) -> dict[tuple[int, int], list[BopEstimate]]:
    """Rows keyed by ``(scene_id, im_id)``, images in first-seen order, rows in given order."""
    groups: dict[tuple[int, int], list[BopEstimate]] = {}
    for row in rows:
        groups.setdefault((row.scene_id, row.im_id), []).append(row)
    return groups
