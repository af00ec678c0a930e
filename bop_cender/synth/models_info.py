"""BOP ``models_info.json`` entries and model folders for procedural parts.

The entry is computed as the BOP toolkit's ``scripts/calc_model_info.py`` does: from the vertices
of the PLY as stored (``write_models`` reloads each file it writes, so the float32 rounding of the
ASCII PLY is in the numbers), the 3D bounding box (``min_*``, ``size_*``) and the diameter, the
largest distance between any two vertices. The diameter is exact but fast: the two farthest
vertices are always vertices of the convex hull, so only those are compared.

Symmetries are written only when non-empty, as in the toolkit's files. :func:`symmetry_deviation`
checks listed symmetries against a mesh (used by the tests, and by anyone adding a model by hand).
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, QhullError
from scipy.spatial.distance import cdist

from bop_cender.data.bop_io import load_ply, save_json, save_ply
from bop_cender.data.models import model_path
from bop_cender.geometry.symmetry import ContinuousSymmetry

if TYPE_CHECKING:
    from bop_cender.synth.parts import Part

#: Model folders per dataset layout: (the main models folder, the evaluation copy).
MODEL_FOLDERS: dict[str, tuple[str, str]] = {
    "dimo": ("models", "models_eval"),
    "tless": ("models_cad", "models_eval"),
    "industrial": ("models", "models_eval"),
}


def models_info_entry(
    mesh: trimesh.Trimesh,
    symmetries_discrete: Sequence[Sequence[float]] = (),
    symmetries_continuous: Sequence[ContinuousSymmetry] = (),
) -> dict:
    """One ``models_info.json`` entry: ``diameter``, ``min_x/y/z``, ``size_x/y/z`` (mm) and symmetries.

    Args:
        mesh: the model as it is stored (all its vertices count, as in the toolkit).
        symmetries_discrete: flattened row-major 4x4 matrices (16 floats), identity excluded.
        symmetries_continuous: continuous rotational symmetries.

    Returns:
        dict with plain Python floats; ``symmetries_discrete`` / ``symmetries_continuous`` only
        when non-empty (continuous as ``{"axis": [3], "offset": [3]}``).
    """
    pts = np.asarray(mesh.vertices, dtype=np.float64)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    size = hi - lo
    entry: dict = {"diameter": points_diameter(pts)}
    entry |= {f"min_{a}": float(v) for a, v in zip("xyz", lo, strict=True)}
    entry |= {f"size_{a}": float(v) for a, v in zip("xyz", size, strict=True)}
    if len(symmetries_discrete):
        entry["symmetries_discrete"] = [
            [float(v) for v in np.asarray(s, dtype=np.float64).ravel()] for s in symmetries_discrete
        ]
    if len(symmetries_continuous):
        entry["symmetries_continuous"] = [
            {"axis": [float(v) for v in s.axis], "offset": [float(v) for v in s.offset]} for s in symmetries_continuous
        ]
    return entry


def points_diameter(points: np.ndarray, chunk: int = 2048) -> float:
    """Largest distance between two of ``points (N, 3)``; exact (farthest pair lies on the hull).

    Falls back to all points when the hull is degenerate (flat or collinear input); the pairwise
    distances are taken in ``chunk``-row blocks so memory stays bounded.
    """
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < 2:
        return 0.0
    with contextlib.suppress(QhullError):  # flat or collinear input: compare all points
        pts = pts[ConvexHull(pts).vertices]
    best = 0.0
    for start in range(0, len(pts), chunk):
        best = max(best, float(cdist(pts[start : start + chunk], pts[start:]).max()))
    return best


def write_models(models_dir: str | Path, parts: Mapping[int, Part]) -> dict[int, dict]:
    """Write ``obj_{id:06d}.ply`` (ASCII, vertex normals, mm) and ``models_info.json`` for ``parts``.

    Each entry is computed from the PLY as written and reloaded (see the module docstring).

    Returns:
        the ``models_info`` dict written, keyed by object id.
    """
    models_dir = Path(models_dir)
    info: dict[int, dict] = {}
    for obj_id, part in sorted(parts.items()):
        path = model_path(models_dir, int(obj_id))
        save_ply(path, part.mesh)
        info[int(obj_id)] = models_info_entry(load_ply(path), part.symmetries_discrete, part.symmetries_continuous)
    save_json(models_dir / "models_info.json", info)
    return info


def write_model_folders(
    root: str | Path, parts: Mapping[int, Part], layout: Literal["dimo", "tless", "industrial"]
) -> dict[str, Path]:
    """Write the model folders of a dataset in ``layout``: DIMO ``models/`` + ``models_eval/``, or
    T-LESS ``models_cad/`` + ``models_eval/``, or industrial ``models/`` + ``models_eval/``.

    The evaluation copy is identical to the main folder for now (no resampling); the same bytes
    are written to both. A folder whose ``models_info.json`` exists (written last) is complete and
    kept, so a run cut off between the folders is finished by the next one. For DIMO the (in real data undocumented) ``models/construction/`` folder
    is created empty, as docs/datasets.md lists it.

    Returns:
        ``{"models": path, "models_eval": path}`` (the first key is ``models_cad`` for T-LESS).
    """
    if layout not in MODEL_FOLDERS:
        raise ValueError(f"layout must be one of {sorted(MODEL_FOLDERS)}, got {layout!r}")
    root = Path(root)
    written: dict[str, Path] = {}
    for name in MODEL_FOLDERS[layout]:
        if not (root / name / "models_info.json").is_file():  # written last: a folder that has it is complete
            write_models(root / name, parts)
        written[name] = root / name
    if layout == "dimo":
        (root / "models" / "construction").mkdir(parents=True, exist_ok=True)
    return written


def model_folders_complete(root: str | Path, layout: Literal["dimo", "tless", "industrial"]) -> bool:
    """Whether every model folder of ``layout`` has its ``models_info.json`` (written last: the folder is
    complete), so that :func:`write_model_folders` has nothing to do and the catalogue need not be made."""
    return all((Path(root) / name / "models_info.json").is_file() for name in MODEL_FOLDERS[layout])


def symmetry_deviation(
    mesh: trimesh.Trimesh,
    R: np.ndarray,
    t: np.ndarray,
    search_radius: float,
    both_ways: bool = True,
    chunk_points: int = 200_000,
) -> np.ndarray:
    """How far each transform is from mapping ``mesh`` onto itself, mm (inf: farther than ``search_radius``).

    Samples are the vertices and the face centroids (with their face normals). For a symmetry
    ``T_s = (R_s, t_s)`` each sample is mapped by ``T_s`` (and by ``T_s^-1``) and must land on the
    original surface: a vertex within the returned distance of any face, a face centroid within it
    of a face turned the same way (normals within 45 deg). Centroids matter: rotating a flat flange
    about its axis keeps every vertex on its planar faces, but moves its hole walls into the metal.
    A true symmetry of the tessellation gives ~0; a continuous symmetry of a faceted circle gives
    at most the facets' sagitta. Faces farther than ``search_radius`` are never looked at (this keeps
    the check fast), so a transform with a sample farther than that reports ``inf``. Needs rtree.

    Args:
        mesh: watertight triangle mesh, ``vertices (N, 3)``, ``faces (F, 3)``.
        R: ``(S, 3, 3)`` rotations; t: ``(S, 3)`` translations (mm).
        search_radius: mm; choose it above the tolerance you compare the result with.
        both_ways: also map the samples by ``T_s^-1``. Pass False for a set of transforms closed
            under inversion (a group, BOP's full list, any subset with each element's inverse):
            the inverse's own entry then checks the other direction, at half the cost.
        chunk_points: transformed samples per batch (bounds memory).

    Returns:
        ``(S,)`` largest sample-to-surface distance per transform, mm, or inf.
    """
    R = np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)
    t = np.asarray(t, dtype=np.float64).reshape(-1, 3)
    samples = np.vstack([mesh.vertices, mesh.triangles_center])
    normals = np.vstack([np.zeros_like(mesh.vertices), mesh.face_normals])  # zero: no facing test
    R_all, t_all = R, t
    if both_ways:  # T_s and T_s^-1 for every s: (2S, 3, 3), (2S, 3)
        R_all = np.concatenate([R, R.transpose(0, 2, 1)])
        t_all = np.concatenate([t, -np.einsum("sji,sj->si", R, t)])
    # Two passes: every 8th sample first; one sample with no surface in reach already proves inf,
    # so only the transforms still finite (the likely symmetries) get the other samples.
    first = np.arange(len(samples)) % 8 == 0
    worst = np.zeros(len(R_all))
    for subset in (first, ~first):
        todo = np.flatnonzero(np.isfinite(worst))
        d = _worst_distance(
            mesh, samples[subset], normals[subset], R_all[todo], t_all[todo], search_radius, chunk_points
        )
        worst[todo] = np.maximum(worst[todo], d)
    return np.maximum(worst[: len(R)], worst[len(R) :]) if both_ways else worst


def _worst_distance(
    mesh: trimesh.Trimesh,
    samples: np.ndarray,
    normals: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    radius: float,
    chunk_points: int,
) -> np.ndarray:
    """``(S,)`` largest :func:`_distance_to_like_facing` of ``samples (N, 3)`` mapped by each ``(R, t)``."""
    per_chunk = max(1, chunk_points // max(len(samples), 1))
    worst = np.zeros(len(R))
    for start in range(0, len(R), per_chunk):
        Rc, tc = R[start : start + per_chunk], t[start : start + per_chunk]
        pts = (np.einsum("sij,nj->sni", Rc, samples) + tc[:, None, :]).reshape(-1, 3)
        nrm = np.einsum("sij,nj->sni", Rc, normals).reshape(-1, 3)
        dist = _distance_to_like_facing(mesh, pts, nrm, radius)
        worst[start : start + len(Rc)] = dist.reshape(len(Rc), -1).max(axis=1)
    return worst


def _distance_to_like_facing(mesh: trimesh.Trimesh, pts: np.ndarray, nrm: np.ndarray, radius: float) -> np.ndarray:
    """``(P,)`` distance from each point to the nearest face within ``radius`` whose normal is within
    45 deg of the point's normal (any face when the normal is zero); inf when there is none."""
    ids, counts = mesh.triangles_tree.intersection_v(pts - radius, pts + radius)
    ids, counts = ids.astype(np.int64), counts.astype(np.int64)
    owner = np.repeat(np.arange(len(pts)), counts)
    closest = trimesh.triangles.closest_point(mesh.triangles[ids], pts[owner])
    d = np.linalg.norm(closest - pts[owner], axis=1)
    facing = np.einsum("ij,ij->i", mesh.face_normals[ids], nrm[owner])
    ok = (np.linalg.norm(nrm[owner], axis=1) == 0) | (facing >= np.cos(np.pi / 4))
    d[~ok | (d > radius)] = np.inf
    out = np.full(len(pts), np.inf)
    np.minimum.at(out, owner, d)
    return out
