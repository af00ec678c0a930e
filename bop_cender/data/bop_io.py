"""Reading and writing BOP files: JSON, PLY, 16-bit depth PNGs, masks; atomic writes.

Every reader raises :class:`DatasetError` naming the file (and the line for JSON) instead of a
bare exception, and every writer writes to a temporary file beside the target and renames it,
so an interrupted run never leaves a half-written file.
"""

from __future__ import annotations

import errno
import json
import math
import os
import re
import sys
import tempfile
import threading
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from bop_cender.data.ply_ascii import ascii_mesh, check_mesh
from bop_cender.errors import BopCenderError, ConfigError, DatasetError


def read_text(path: str | Path, error: type[BopCenderError] = DatasetError, what: str = "file") -> str:
    """A UTF-8 text file's content (a leading UTF-8 byte-order mark dropped, as Windows editors write one), or
    one ``error`` naming the file: missing, unreadable (a folder, no permission) or not UTF-8."""
    path = Path(path)
    try:
        return path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise error(f"{what} not found", file=path) from None
    except IsADirectoryError:
        raise error(f"is a directory, expected {_a(what)}", file=path) from None
    except UnicodeDecodeError as e:
        raise error(f"not UTF-8 text (byte {e.start})", file=path) from None
    except OSError as e:
        raise error(f"cannot read: {e.strerror}", file=path) from None


def _a(noun: str) -> str:
    return f"{'an' if noun[:1] in 'aeiou' else 'a'} {noun}"


def require_file(
    path: str | Path, what: str, error: type[BopCenderError] = DatasetError, field: str | None = None
) -> Path:
    """``path`` if it is a file; else one ``error`` that says what is there instead ("not found" or "is a
    directory"), so that a folder given where a file is expected is not reported as missing."""
    path = Path(path)
    if path.is_dir():
        raise error(f"is a directory, expected {_a(what)}", file=path, field=field)
    if not path.is_file():
        raise error(f"{what} not found", file=path, field=field)
    return path


def require_dir(
    path: str | Path, what: str, error: type[BopCenderError] = DatasetError, field: str | None = None
) -> Path:
    """``path`` if it is a folder; else one ``error`` that says what is there instead ("not found" or "is a
    file"), so that a file given where a folder is expected is not reported as missing."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise error(f"is a file, expected {_a(what)}", file=path, field=field)
    if not path.is_dir():
        raise error(f"{what} not found", file=path, field=field)
    return path


def check_output_dir(path: str | Path, field: str = "--out") -> Path:
    """``path`` if a folder can be written there: refused (ConfigError) when it, or a folder above it, is a
    file. Called before any work, so that a command does not compute for minutes and then fail to write."""
    path = Path(path)
    _check_folders_above(path, (path, *path.parents), field)
    return path


def _check_folders_above(path: Path, folders: Iterable[Path], field: str) -> None:
    for above in folders:
        if above.exists():
            if not above.is_dir():
                where = "exists and is not a directory" if above == path else f"{above} is a file, not a folder"
                raise ConfigError(where, file=path, field=field)
            return


def check_output_file(path: str | Path, field: str = "--out") -> Path:
    """``path`` if a file can be written there: refused (ConfigError) when it is a directory or a folder above
    it is a file (see :func:`check_output_dir`)."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError("is a directory, expected an output file", file=path, field=field)
    _check_folders_above(path, path.parents, field)
    return path


def load_json(path: str | Path, keys_to_int: bool = False, error: type[BopCenderError] = DatasetError) -> Any:
    """Load a JSON file; with ``keys_to_int`` turn digit keys of dicts into ints, as BOP does.

    A key repeated in one object is refused: ``json`` would keep its last value and drop the others without a
    word (two estimates of one image, a pose's ``score`` given twice). ``json.dump`` never writes one, so it
    is always a hand edit or a broken writer. With ``keys_to_int``, ``"1"`` and ``"01"`` are the same key.

    Raises:
        DatasetError (or ``error``): the file is missing, unreadable or not valid JSON (with line and column),
            or an object repeats a key (``field``: the key).
    """
    text = read_text(path, error)
    try:
        return json.loads(text, object_pairs_hook=_int_keys if keys_to_int else _unique_keys)
    except json.JSONDecodeError as e:
        # json's own messages may end in "at" ("Unterminated string starting at"): "at at line 2" read badly
        where = f"line {e.lineno}, column {e.colno}"
        what = e.msg[: -len(" at")] if e.msg.endswith(" at") else e.msg
        raise error(f"malformed JSON: {what} at {where}", file=Path(path)) from None
    except _RepeatedKey as e:
        raise error(
            f"a JSON object repeats the key {e.key!r} (only its last value would be read)",
            file=Path(path),
            field=str(e.key),
        ) from None


class _RepeatedKey(Exception):
    def __init__(self, key: Any) -> None:
        super().__init__(key)
        self.key = key


def _unique_keys(pairs: list[tuple[Any, Any]]) -> dict:
    """A dict of ``pairs``, refusing a repeated key (:class:`_RepeatedKey`)."""
    out = dict(pairs)
    if len(out) != len(pairs):
        seen: set[Any] = set()
        for key, _ in pairs:
            if key in seen:
                raise _RepeatedKey(key)
            seen.add(key)
    return out


_INT_KEY = re.compile(r"-?[0-9]+")


def _int_keys(pairs: list[tuple[str, Any]]) -> dict:
    """Keys of ASCII digits (an optional minus) as ints; others (``"²"``, ``"--1"``, ``"٣"``) stay strings for the
    caller to refuse by name (``str.isdigit`` takes ``"²"``, which ``int()`` refuses). A key repeated (``"1"``
    and ``"01"`` included) raises :class:`_RepeatedKey`."""
    return _unique_keys([(int(k) if isinstance(k, str) and _INT_KEY.fullmatch(k) else k, v) for k, v in pairs])


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


#: The process's umask (read once: os.umask can only be read by setting it).
_UMASK = _current_umask()


@contextmanager
def atomic_path(path: str | Path, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` only if the block succeeds."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or path.suffix or ".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    os.chmod(tmp_path, 0o666 & ~_UMASK)  # mkstemp makes 0600; the file gets what open() would have given it
    try:
        try:
            yield tmp_path
            os.replace(tmp_path, path)
        except OSError as e:
            raise _naming(e, tmp_path, path) from None
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def _naming(error: OSError, tmp: Path, path: Path) -> OSError:
    """``error`` naming ``path`` where it names the temporary file ``tmp``: the user never asked for ``tmp``
    (and it is gone by the time they read the message)."""
    if error.filename is None or Path(error.filename) != tmp:
        return error
    return type(error)(error.errno, error.strerror, str(path))


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (UTF-8)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_texts_atomic(files: Mapping[str | Path, str]) -> None:
    """Write several files as one unit: all of them, or (on any error) none, the previous contents kept.

    Files that belong together (a scores JSON and its errors CSV) must never be left half updated: a
    new CSV beside an old JSON reads as one consistent result. Each text goes to a temporary file
    first; only when every one is written are the targets replaced, the old ones moved aside until all
    are in place and put back if one replacement fails.
    """
    targets = [Path(p) for p in files]
    temps: list[Path] = []
    moved: list[tuple[Path, Path]] = []  # (target, its previous content moved aside)
    placed: list[Path] = []
    try:
        for target, text in zip(targets, files.values(), strict=True):
            target.parent.mkdir(parents=True, exist_ok=True)
            fd, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=target.suffix or ".tmp", dir=target.parent)
            os.close(fd)
            tmp = Path(name)
            temps.append(tmp)
            os.chmod(tmp, 0o666 & ~_UMASK)
            try:
                tmp.write_text(text, encoding="utf-8")
            except OSError as e:
                raise _naming(e, tmp, target) from None
        for target, tmp in zip(targets, temps, strict=True):
            if target.is_dir():
                raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), str(target))
            if target.exists():
                fd, name = tempfile.mkstemp(prefix=f".{target.name}.old.", dir=target.parent)
                os.close(fd)
                os.replace(target, name)
                moved.append((target, Path(name)))
            try:
                os.replace(tmp, target)
            except OSError as e:
                raise _naming(e, tmp, target) from None
            placed.append(target)
    except BaseException:
        for target in placed:
            target.unlink(missing_ok=True)
        for target, old in moved:
            os.replace(old, target)
        moved = []
        raise
    finally:
        for tmp in temps:
            tmp.unlink(missing_ok=True)
        for _target, old in moved:
            old.unlink(missing_ok=True)


def _json_default(o: Any) -> Any:
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def dumps_bop_json(content: Any) -> str:
    """Serialise like the BOP toolkit's ``save_json``: dicts by sorted key, one entry per line."""
    if isinstance(content, Mapping):
        items = sorted(content.items(), key=lambda kv: _sort_key(kv[0]))
        lines = [f"  {json.dumps(str(k))}: {json.dumps(v, sort_keys=True, default=_json_default)}" for k, v in items]
        return "{\n" + ",\n".join(lines) + "\n}"
    if isinstance(content, list):
        lines = [f"  {json.dumps(v, sort_keys=True, default=_json_default)}" for v in content]
        return "[\n" + ",\n".join(lines) + "\n]"
    return json.dumps(content, sort_keys=True, default=_json_default)


def _sort_key(k: Any) -> tuple:
    s = str(k)
    return (0, int(s), s) if s.lstrip("-").isdigit() else (1, 0, s)


def save_json(path: str | Path, content: Any) -> None:
    """Write BOP-style JSON atomically (digit keys sorted numerically)."""
    write_text_atomic(path, dumps_bop_json(content) + "\n")


def load_ply(path: str | Path):
    """Load a triangle mesh (mm) with trimesh, keeping vertices exactly as stored (no merging).

    Checked as :func:`bop_cender.data.ply_ascii.check_mesh` checks (vertices, finite, faces, indices); an
    ASCII PLY is first read line by line by :func:`bop_cender.data.ply_ascii.ascii_mesh` (trimesh takes
    a file cut short for a mesh with fewer faces than its header declares).

    Returns:
        trimesh.Trimesh with ``vertices (N, 3)`` float64 and ``faces (F, 3)``.
    """
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise DatasetError("model file not found", file=path)
    ascii_mesh(path)  # raises on a truncated or malformed ASCII PLY; cached, and what evaluation reads anyway
    try:
        mesh = trimesh.load(path, process=False, force="mesh")
    except Exception as e:  # trimesh raises many types on corrupt input
        raise DatasetError(f"cannot read PLY: {e}", file=path) from None
    if not isinstance(mesh, trimesh.Trimesh):
        raise DatasetError("expected a triangle mesh", file=path)
    check_mesh(mesh.vertices, mesh.faces, path)  # the checks of the scorer's own reader (ply_ascii)
    return mesh


def save_ply(path: str | Path, mesh, binary: bool = False) -> None:
    """Write a mesh as PLY with vertex normals, atomically (ASCII by default, as BOP models)."""
    import trimesh

    with atomic_path(path) as tmp:
        data = trimesh.exchange.ply.export_ply(
            mesh, encoding="binary" if binary else "ascii", include_attributes=False, vertex_normal=True
        )
        tmp.write_bytes(data)


_QUIET_LOCK = threading.Lock()
_quiet_depth = 0  # how many threads are inside quiet_stderr()
_saved_stderr: int | None = None


@contextmanager
def quiet_stderr() -> Iterator[None]:
    """Silence what C libraries write to the process's stderr (file descriptor 2) inside the block.

    The image decoders print their own lines (``libpng error: IDAT: CRC error``) before returning the
    failure that we report as one error: the user would read a stray line first. Python's own
    ``sys.stderr`` writes of other threads are silenced too while a decode runs (a progress bar misses
    an update), which is why the block is kept to the decode alone. Nested and concurrent blocks share
    one redirection (counted under a lock), so that the first to leave never restores too early and
    the last always restores.
    """
    global _quiet_depth, _saved_stderr
    with _QUIET_LOCK:
        if _quiet_depth == 0:
            try:
                sys.stderr.flush()
                saved = os.dup(2)
            except (OSError, ValueError, AttributeError):  # no stderr to silence (closed, or replaced)
                saved = None
            if saved is not None:
                devnull = os.open(os.devnull, os.O_WRONLY)
                os.dup2(devnull, 2)
                os.close(devnull)
            _saved_stderr = saved
        _quiet_depth += 1
    try:
        yield
    finally:
        with _QUIET_LOCK:
            _quiet_depth -= 1
            if _quiet_depth == 0 and _saved_stderr is not None:
                os.dup2(_saved_stderr, 2)
                os.close(_saved_stderr)
                _saved_stderr = None


def _imread(path: Path, flags: int) -> np.ndarray:
    import cv2

    require_file(path, "image")
    with quiet_stderr():  # libpng's own message would come before ours
        img = cv2.imread(str(path), flags)
    if img is None:
        raise DatasetError("cannot decode image", file=path)
    return img


def load_depth(path: str | Path, depth_scale: float) -> np.ndarray:
    """Depth image in mm ``(H, W)`` float32 from a 16-bit PNG: ``png * depth_scale`` (0 = no depth).

    Only a single-channel 16-bit image is depth: an 8-bit one (a visualisation, a mask, a re-save
    that lost the bit depth) holds values of another unit entirely, and VSD would score against it
    without a word.
    """
    import cv2

    img = _imread(Path(path), cv2.IMREAD_UNCHANGED)
    if img.ndim != 2:
        raise DatasetError(f"expected a single-channel depth image, got shape {img.shape}", file=path)
    if img.dtype != np.uint16:
        raise DatasetError(f"expected a 16-bit depth image, got {8 * img.dtype.itemsize}-bit ({img.dtype})", file=path)
    return img.astype(np.float32) * np.float32(depth_scale)


def save_depth(path: str | Path, depth_mm: np.ndarray, depth_scale: float) -> None:
    """Write depth in mm as a uint16 PNG with ``png = round(depth / depth_scale)``, atomically."""
    units = np.round(np.asarray(depth_mm, dtype=np.float64) / depth_scale)
    if not np.isfinite(units).all() or units.min(initial=0) < 0 or units.max(initial=0) > 65535:
        raise ValueError(
            f"depth must be finite and within [0, {65535 * depth_scale:g}] mm at depth_scale {depth_scale} (uint16)"
        )
    write_image(path, units.astype(np.uint16))


def load_mask(path: str | Path) -> np.ndarray:
    """Binary mask ``(H, W)`` bool from a PNG (non-zero = inside)."""
    import cv2

    img = _imread(Path(path), cv2.IMREAD_UNCHANGED)
    if img.ndim == 3:
        img = img.max(axis=2)
    return img > 0


def load_rgb(path: str | Path) -> np.ndarray:
    """Colour image ``(H, W, 3)`` uint8 in RGB order."""
    import cv2

    img = _imread(Path(path), cv2.IMREAD_COLOR)
    return img[:, :, ::-1].copy()


def write_image(path: str | Path, image: np.ndarray, jpeg_quality: int = 95) -> None:
    """Write an image atomically: PNG (uint8/uint16, lossless) or JPEG by suffix. RGB input order."""
    import cv2

    path = Path(path)
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 3:
        img = img[:, :, ::-1]
    params = [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality] if path.suffix.lower() in (".jpg", ".jpeg") else []
    ok, buf = cv2.imencode(path.suffix, np.ascontiguousarray(img), params)
    if not ok:
        raise OSError(f"cannot encode image {path}")
    with atomic_path(path) as tmp:
        tmp.write_bytes(buf.tobytes())


def require_keys(entry: Mapping, keys: tuple[str, ...], file: Path, where: str) -> None:
    """Raise a DatasetError naming the first missing key of ``entry``."""
    if not isinstance(entry, Mapping):
        raise DatasetError(f"expected an object, got {type(entry).__name__}", file=file, field=where)
    for k in keys:
        if k not in entry:
            raise DatasetError(f"missing key '{k}'", file=file, field=where)


def load_image_dict(path: Path) -> dict[int, Any]:
    """A BOP per-image JSON file (keys = image ids, ``"0"``, ``"1"``, ...) with int keys in ascending order, or a
    DatasetError."""
    content = load_json(path, keys_to_int=True)
    if not isinstance(content, dict):
        raise DatasetError(f"expected an object keyed by image id, got {type(content).__name__}", file=path)
    for key in content:
        if not isinstance(key, int) or key < 0:
            raise DatasetError("expected image ids (non-negative integers) as keys", file=path, field=repr(key))
    return dict(sorted(content.items()))


def check_same_image_ids(files: Mapping[Path, Iterable[int]]) -> None:
    """The image-id sets of the given files must be identical (the first file is the reference); else one
    DatasetError naming the file that differs and a few of the ids."""
    items = [(path, set(ids)) for path, ids in files.items()]
    ref_path, ref = items[0]
    for path, ids in items[1:]:
        if ids != ref:
            missing, extra = sorted(ref - ids), sorted(ids - ref)
            parts = [f"missing {few_ids(missing)}"] * bool(missing) + [
                f"not in {ref_path.name}: {few_ids(extra)}"
            ] * bool(extra)
            raise DatasetError(
                f"image ids differ from {ref_path.name} ({'; '.join(parts)}); expected the same set",
                file=path,
                field="image ids",
            )


def few_ids(ids: Sequence[int], n: int = 8) -> str:
    """The first ``n`` ids, comma-separated, and how many there are in all when there are more ("none" if empty)."""
    if not ids:
        return "none"
    return ", ".join(map(str, ids[:n])) + (f", ... ({len(ids)} in all)" if len(ids) > n else "")


def as_int(value: Any, file: Path, where: str, strings: bool = False) -> int:
    """An int from a JSON value: an int or an integral float (with ``strings``, also a numeric string);
    never a bool, NaN or infinity; else a DatasetError naming the file and field."""
    if isinstance(value, int) and not isinstance(value, bool):
        return value
    if isinstance(value, float) and value.is_integer():  # False for NaN and infinities
        return int(value)
    if strings and isinstance(value, str):
        try:
            return int(value.strip())
        except ValueError:
            pass
    raise DatasetError(f"expected an integer, got {value!r}", file=file, field=where)


def as_number(value: Any, file: Path, where: str) -> float:
    """A finite float from a JSON value (int, float or numeric string; not a bool), else a DatasetError."""
    try:
        if isinstance(value, bool):
            raise TypeError("a bool is not a number")
        x = float(value)
    except (TypeError, ValueError):
        raise DatasetError(f"expected a number, got {value!r}", file=file, field=where) from None
    if not math.isfinite(x):
        raise DatasetError(f"expected a finite number, got {value!r}", file=file, field=where)
    return x


def image_size(path: str | Path) -> tuple[int, int]:
    """``(width, height)`` of a PNG or JPEG (read from its header, :mod:`bop_cender.data.image_header`) or any
    image cv2 decodes.

    Raises:
        DatasetError: the file is missing, not an image, or a PNG or JPEG with a cut or malformed header.
    """
    return image_shape(path)[:2]


def image_shape(path: str | Path) -> tuple[int, int, int]:
    """``(width, height, channels)`` of an image as :func:`image_size` reads it (channels as decoded unchanged: 1 grey,
    3 colour, 4 colour + alpha).

    Raises:
        DatasetError: as :func:`image_size`.
    """
    from bop_cender.data.image_header import read_image_header

    path = Path(path)
    header = read_image_header(path)
    if header is not None:
        return header.width, header.height, header.channels
    import cv2

    img = _imread(path, cv2.IMREAD_UNCHANGED)
    return int(img.shape[1]), int(img.shape[0]), 1 if img.ndim == 2 else int(img.shape[2])
