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


@lru_cache(maxsize=64)
def _ascii_ply(path: str) -> tuple[np.ndarray, np.ndarray | None] | None:
    """``(vertices, faces)`` of an ASCII PLY, vertices parsed with ``float()``; None for a binary PLY.

    ``faces`` is None when the file has no triangle list right after the vertices (other layouts are
    left to trimesh).
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
        if not any(h.startswith("format ascii") for h in header):
            return None
        elements = [h.split() for h in header if h.startswith("element")]
        n_pts, props, in_vertex = 0, [], False
        for h in header:
            if h.startswith("element"):
                in_vertex = h.startswith("element vertex")
                if in_vertex:
                    n_pts = int(h.split()[-1])
            elif h.startswith("property") and in_vertex:
                props.append(h.split()[-1])
        try:
            cols = [props.index(a) for a in ("x", "y", "z")]
        except ValueError:
            raise DatasetError("PLY vertices have no x, y, z properties", file=path) from None
        pts = np.empty((n_pts, 3), dtype=np.float64)
        for i in range(n_pts):
            fields = f.readline().split()
            pts[i] = [float(fields[c]) for c in cols]
        pts.setflags(write=False)
        faces = None
        names = [e[1] for e in elements]
        if names[:2] == ["vertex", "face"]:
            n_faces = int(elements[1][2])
            rows = [f.readline().split() for _ in range(n_faces)]
            if all(len(r) >= 4 and r[0] == b"3" for r in rows):
                faces = np.array([r[1:4] for r in rows], dtype=np.int64).reshape(-1, 3)
    return pts, faces
