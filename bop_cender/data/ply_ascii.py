"""ASCII PLY read as the BOP toolkit reads it: vertices parsed with Python's ``float()``, triangles as int64.

The toolkit's ``inout.load_ply`` turns the text of an ASCII PLY into float64 with ``float()``; trimesh (our
mesh loader) reads an ASCII ``property float`` as float32 first. The two differ by ~1e-7 relative (e.g.
``18.70469475`` vs ``18.704694747924805``), which moves MSSD by ~1e-9 mm, enough to flip an error lying on a
threshold. This reader also needs neither trimesh nor SciPy (a fast cold start, a light render process).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from bop_cender.errors import DatasetError


@dataclass(frozen=True)
class MeshArrays:
    """A triangle mesh as plain arrays: ``vertices (N, 3)`` float64 (mm) and ``faces (F, 3)`` int64."""

    vertices: np.ndarray
    faces: np.ndarray


def ascii_mesh(path: str | Path) -> MeshArrays | None:
    """Vertices and triangles of an ASCII PLY without trimesh (its import alone costs ~0.4 s of a cold
    ``score``); None for a binary PLY or one this reader does not handle (then use trimesh)."""
    parsed = _ascii_ply(str(Path(path).resolve()))
    if parsed is None or parsed[1] is None:
        return None
    return MeshArrays(parsed[0], parsed[1])


def ascii_vertices(path: str) -> np.ndarray | None:
    """``(N, 3)`` float64 vertices of an ASCII PLY (read-only, cached per resolved path); None for a binary PLY."""
    parsed = _ascii_ply(path)
    return None if parsed is None else parsed[0]


def check_mesh(vertices: np.ndarray, faces: np.ndarray | None, path: str | Path) -> None:
    """Refuse a model no evaluation can use, whichever reader read it (this one or trimesh, ``load_ply``).

    Every reader of a model file applies the same checks, so that a broken model fails as one error
    naming the file rather than as a traceback deep in the renderer or, worse, a plausible score (NaN
    vertices make every MSSD NaN, which no threshold accepts; out-of-range indices read other memory).

    Raises:
        DatasetError: no vertices, NaN or infinite coordinates, no faces (with ``faces`` given), faces
            that are not triangles, or vertex indices outside ``[0, vertices)``.
    """
    vertices = np.asarray(vertices)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) == 0:
        raise DatasetError(f"expected a mesh with vertices (N, 3), got shape {vertices.shape}", file=path)
    bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
    if len(bad):
        raise DatasetError(
            f"{len(bad)} vertex coordinate(s) NaN or infinite (first: vertex {bad[0]})", file=path, field="vertex"
        )
    if faces is None:
        return
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise DatasetError(f"expected triangles (F, 3), got shape {faces.shape}", file=path, field="face")
    if len(faces) == 0:
        raise DatasetError("expected a triangle mesh: the file has no faces", file=path, field="face")
    out = np.flatnonzero(((faces < 0) | (faces >= len(vertices))).any(axis=1))
    if len(out):
        raise DatasetError(
            f"{len(out)} face(s) index vertices outside 0..{len(vertices) - 1} (first: face {out[0]},"
            f" {faces[out[0]].tolist()})",
            file=path,
            field="face",
        )


@lru_cache(maxsize=64)
def _ascii_ply(path: str) -> tuple[np.ndarray, np.ndarray | None] | None:
    """``(vertices, faces)`` of an ASCII PLY, vertices parsed with ``float()``; None for a binary PLY.

    ``faces`` is None when the file has no triangle list right after the vertices (other layouts, such as
    polygons, are left to trimesh, which :func:`check_mesh` checks in turn). Everything read here is
    checked (:func:`check_mesh`), a truncated or malformed line included.

    Raises:
        DatasetError: not a PLY, a malformed header or line, a truncated file, or a mesh that fails
            :func:`check_mesh`.
    """
    with open(path, "rb") as f:
        header = []
        while True:
            line = f.readline()
            if not line:
                raise DatasetError("PLY header has no end_header", file=path)
            text = line.decode("utf8", errors="replace").strip()
            header.append(text)
            if text == "end_header":
                break
        if header[0] != "ply":
            raise DatasetError("not a PLY file (expected 'ply' on the first line)", file=path)
        if not any(h.startswith("format ascii") for h in header):
            return None
        elements: list[tuple[str, int]] = []
        props: list[str] = []
        for n, h in enumerate(header, start=1):
            words = h.split()
            if words[:1] == ["element"]:
                if len(words) != 3 or not words[2].isdigit():
                    raise DatasetError(f"expected 'element NAME COUNT', got {h!r}", file=path, field=f"line {n}")
                elements.append((words[1], int(words[2])))
            elif words[:1] == ["property"] and elements and elements[-1][0] == "vertex":
                if words[1:2] == ["list"]:
                    return None  # vertices of varying length: left to trimesh
                props.append(words[-1])
        try:
            cols = [props.index(a) for a in ("x", "y", "z")]
        except ValueError:
            raise DatasetError("PLY vertices have no x, y, z properties", file=path) from None
        counts = dict(elements)
        n_pts = counts.get("vertex", 0)
        if elements[:1] != [("vertex", n_pts)]:
            return None  # another element first: left to trimesh
        line_no = len(header)
        pts = np.empty((n_pts, 3), dtype=np.float64)
        for i in range(n_pts):
            line_no += 1
            fields = _line(f, path, line_no, f"vertex {i} of {n_pts}")
            if len(fields) != len(props):
                end = " (the file ends there: truncated?)" if not f.peek(1) else ""
                raise DatasetError(
                    f"expected {len(props)} values for vertex {i}, got {len(fields)}{end}",
                    file=path,
                    field=f"line {line_no}",
                )
            try:
                pts[i] = [float(fields[c]) for c in cols]
            except ValueError:
                raise DatasetError(f"expected numbers for vertex {i}", file=path, field=f"line {line_no}") from None
        pts.setflags(write=False)
        faces = None
        if [e[0] for e in elements[:2]] == ["vertex", "face"]:
            n_faces = elements[1][1]
            rows = []
            for k in range(n_faces):
                line_no += 1
                row = _line(f, path, line_no, f"face {k} of {n_faces}")
                if not row or not row[0].isdigit() or len(row) != int(row[0]) + 1:
                    end = " (the file ends there: truncated?)" if not f.peek(1) else ""
                    raise DatasetError(
                        f"expected a vertex count and that many indices for face {k}{end}",
                        file=path,
                        field=f"line {line_no}",
                    )
                rows.append(row)
            if all(len(r) == 4 and r[0] == b"3" for r in rows):
                try:
                    faces = np.array([r[1:4] for r in rows], dtype=np.int64).reshape(-1, 3)
                except ValueError:
                    raise DatasetError("expected integer vertex indices in the faces", file=path) from None
    check_mesh(pts, faces, path)
    return pts, faces


def _line(f, path: str, line_no: int, what: str) -> list[bytes]:
    """The next line's fields; a missing line is a truncated file (else an IndexError, or a shorter mesh)."""
    line = f.readline()
    if not line:
        raise DatasetError(f"truncated: the file ends before {what}", file=path, field=f"line {line_no}")
    return line.split()
