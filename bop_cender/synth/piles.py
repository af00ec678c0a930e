"""Dense piles of parts on a carrier: stable resting poses dropped straight down until first contact.

Why not a physics engine: DIMO's piles are dense, stacked and overlapping, and all we need is that
every part rests on something (the carrier or another part) and that no two solids interpenetrate
by more than ``max_penetration_mm``. A vertical drop with exact first-contact distances gives that
without simulation, deterministically from one ``numpy.random.Generator``.

The drop of a moving part onto the placed geometry (carrier + parts already placed, all in world
frame, world z up, mm) is the minimum over two families of vertical rays:
- the moving part's contact points cast down (-z) against the placed geometry, and
- the placed geometry's contact points cast up (+z) against the moving part.
Contact points are the vertices (vertex-face contacts: exact) plus points along the non-flat edges,
denser on sharper edges (edge-edge contacts: within about half of ``edge_spacing_mm``). A final
containment check (ray parity) of contact points and surface samples of each part against its
neighbours then rejects the rare drop that still penetrates deeper than ``max_penetration_mm``.
Each part gets ``candidates`` valid drops (other rest pose, yaw, position) and keeps the one that
comes to rest lowest; a part with no valid drop in ``max_tries`` attempts is left out (logged).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
import trimesh

from bop_cender.geometry.poses import compose, make_pose, transform_points
from bop_cender.geometry.rotations import axis_angle_to_rotmat

logger = logging.getLogger(__name__)

#: Height above the highest placed point at which a part starts its drop (mm).
_DROP_CLEARANCE_MM = 5.0


@dataclass(frozen=True, eq=False)
class Placement:
    """One part of a pile.

    Attributes:
        part_index: index into the ``meshes`` passed to :func:`build_pile`.
        T_world_model: ``(4, 4)`` float64 model-to-world pose, mm.
    """

    part_index: int
    T_world_model: np.ndarray


class Composition(StrEnum):
    """Which part types a pile uses (DIMO compositions are either one type repeated or mixed)."""

    SAME = "same"  # one type, drawn at random, repeated n_parts times
    MIXED = "mixed"  # each part's type drawn uniformly from all meshes


def build_pile(
    meshes: Sequence[trimesh.Trimesh],
    carrier: trimesh.Trimesh,
    T_world_carrier: np.ndarray,
    n_parts: int,
    rng: np.random.Generator,
    *,
    composition: Composition | str | Sequence[int] = Composition.MIXED,
    spread: float | None = None,
    max_penetration_mm: float = 1.0,
    max_tries: int = 12,
    candidates: int = 3,
    edge_spacing_mm: float = 1.0,
    cache: PileGeometryCache | None = None,
) -> list[Placement]:
    """Drop ``n_parts`` parts one by one onto the carrier and onto each other.

    Each part takes a stable resting pose of its own (``trimesh.poses.compute_stable_poses``,
    drawn by probability), a uniform yaw about world z, and an xy position uniform in a disk of
    radius ``spread`` around the carrier's centre, then falls along -z to first contact. Parts keep
    their stable orientation when they land on other parts (no toppling).

    Args:
        meshes: part models in mm (model frame = the mesh's frame), watertight: the penetration
            check skips the containment test against a mesh that is not.
        carrier: carrier model in mm; parts land on whatever of it faces up.
        T_world_carrier: ``(4, 4)`` carrier-to-world pose; world z is up.
        n_parts: number of parts requested.
        rng: the only source of randomness (same seed, same pile).
        composition: ``"same"`` (one random type repeated), ``"mixed"`` (any type per part) or a
            sequence of mesh indices to draw from (``[3]``: only type 3).
        spread: radius (mm) of the disk of drop positions (kept inside the carrier's xy bounds);
            default ``0.5 * sqrt(n_parts * mean(a * b))`` with ``a, b`` the two largest extents of
            each part, so that the resting footprints cover the disk about once: parts touch,
            overlap in xy and stack.
        max_penetration_mm: deepest allowed overlap of two solids.
        max_tries: attempts per part before it is left out.
        candidates: valid drops tried per part; the one that comes to rest lowest is kept, so parts
            fill gaps instead of balancing on top of the pile (1: first valid drop, tallest piles).
        edge_spacing_mm: spacing of contact points along edges (edge-edge contact accuracy).
        cache: per-mesh derived data kept between piles (a generator keeps one per process); None = a
            fresh one (stable poses are then computed again for this pile).

    Returns:
        The placed parts in drop order; fewer than ``n_parts`` when some could not be placed
        (a warning is logged saying how many and why).
    """
    if n_parts < 0 or not meshes or candidates < 1:
        raise ValueError(
            f"need n_parts >= 0, candidates >= 1 and a mesh; got {n_parts}, {candidates}, {len(meshes)} meshes"
        )
    types = choose_part_indices(len(meshes), n_parts, composition, rng)
    cache = PileGeometryCache() if cache is None else cache
    data = [cache.get(m, edge_spacing_mm) for m in meshes]
    if spread is None:
        footprints = [float(np.prod(np.sort(data[i].extents)[1:])) for i in types] or [1.0]
        spread = 0.5 * float(np.sqrt(max(n_parts, 1) * np.mean(footprints)))
    scene = _PlacedScene(carrier.copy().apply_transform(np.asarray(T_world_carrier, dtype=np.float64)), edge_spacing_mm)
    lo, hi = scene.meshes[0].bounds
    centre_xy = (lo[:2] + hi[:2]) / 2.0

    placements: list[Placement] = []
    failures: list[str] = []
    for index in types:
        drops: list[np.ndarray] = []
        for _ in range(max_tries):
            T = _try_drop(data[index], scene, centre_xy, spread, rng, max_penetration_mm)
            if T is not None:
                drops.append(T)
                if len(drops) == candidates:
                    break
        if not drops:
            failures.append(f"part {len(placements) + len(failures)} (mesh {index})")
            continue
        # settle into gaps as gravity would: keep the drop whose bbox centre comes to rest lowest
        T = min(drops, key=lambda T: float((T[:3, :3] @ data[index].centre + T[:3, 3])[2]))
        placements.append(Placement(int(index), T))
        scene.add(meshes[index].copy().apply_transform(T), data[index], T)
    if failures:
        logger.warning(
            "build_pile placed %d of %d parts: no drop onto the carrier without penetration > %.2f mm "
            "in %d tries for %s",
            len(placements),
            n_parts,
            max_penetration_mm,
            max_tries,
            ", ".join(failures),
        )
    return placements


def choose_part_indices(
    n_types: int, n_parts: int, composition: Composition | str | Sequence[int], rng: np.random.Generator
) -> np.ndarray:
    """Mesh index ``(n_parts,)`` int64 of every part of a pile, by composition (see :func:`build_pile`)."""
    if isinstance(composition, str):
        composition = Composition(composition)
        if composition is Composition.SAME:
            return np.full(n_parts, rng.integers(n_types), dtype=np.int64)
        return rng.integers(n_types, size=n_parts).astype(np.int64)
    allowed = np.asarray(composition, dtype=np.int64)
    if allowed.size == 0 or allowed.min() < 0 or allowed.max() >= n_types:
        raise ValueError(f"composition indices must lie in [0, {n_types}), got {list(allowed)}")
    return allowed[rng.integers(allowed.size, size=n_parts)]


def stable_poses(mesh: trimesh.Trimesh, cache: PileGeometryCache | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Resting poses ``(P, 4, 4)`` (model to a frame where the part lies on z = 0) and probabilities ``(P,)``.

    ``compute_stable_poses`` takes tens of ms per mesh: pass a ``cache`` to compute them once per geometry.
    """
    d = (PileGeometryCache() if cache is None else cache).get(mesh, 1.0)
    return d.rest_poses.copy(), d.rest_probs.copy()


def penetration_depth(mesh: trimesh.Trimesh, points: np.ndarray) -> float:
    """Deepest point of ``points (N, 3)`` inside the watertight ``mesh``, in mm (0 if none is inside).

    Ray-parity containment first (cheap, embree), then the exact distance to the surface for the few inside.
    """
    lo, hi = mesh.bounds
    near = np.all((points >= lo) & (points <= hi), axis=1)
    if not near.any():
        return 0.0
    candidates = points[near]
    inside = mesh.contains(candidates)
    if not inside.any():
        return 0.0
    _, dist, _ = mesh.nearest.on_surface(candidates[inside])
    return float(dist.max())


@dataclass(frozen=True, eq=False)
class _MeshData:
    """Per-mesh values reused by every drop: all points in model coordinates, mm."""

    mesh: trimesh.Trimesh  # the model (or one with the same geometry hash)
    rest_poses: np.ndarray  # (P, 4, 4)
    rest_probs: np.ndarray  # (P,), sums to 1
    contact_points: np.ndarray  # (C, 3) vertices + edge samples
    check_points: np.ndarray  # (C + S, 3) contact points + area samples
    extents: np.ndarray  # (3,)
    centre: np.ndarray  # (3,) bbox centre


class PileGeometryCache:
    """Per-mesh values every drop reuses (stable poses, contact points, check samples), computed once per geometry.

    Keyed by the mesh's geometry hash and the edge spacing; holds at most ``max_entries`` meshes (cleared when
    full). The values depend only on the geometry, so a cache changes speed, never a pile.
    """

    def __init__(self, max_entries: int = 256) -> None:
        self.max_entries = max_entries
        self._data: dict[tuple[str, float], _MeshData] = {}

    def get(self, mesh: trimesh.Trimesh, edge_spacing_mm: float) -> _MeshData:
        key = (mesh.identifier_hash, float(edge_spacing_mm))
        if key not in self._data:
            if len(self._data) >= self.max_entries:
                self._data.clear()
            self._data[key] = _mesh_data(mesh, edge_spacing_mm)
        return self._data[key]


def _mesh_data(mesh: trimesh.Trimesh, edge_spacing_mm: float) -> _MeshData:
    poses, probs = trimesh.poses.compute_stable_poses(mesh)
    contact = _contact_points(mesh, edge_spacing_mm)
    n_area = int(np.clip(mesh.area / 4.0, 200, 4000))  # about one sample per 2x2 mm, bounded
    area = trimesh.sample.sample_surface(mesh, n_area, seed=0)[0]
    return _MeshData(
        mesh=mesh.copy(),
        rest_poses=np.asarray(poses, dtype=np.float64),
        rest_probs=np.asarray(probs, dtype=np.float64) / np.sum(probs),
        contact_points=contact,
        check_points=np.concatenate([contact, area]),
        extents=np.asarray(mesh.extents, dtype=np.float64),
        centre=np.asarray(mesh.bounds, dtype=np.float64).mean(axis=0),
    )


def _contact_points(mesh: trimesh.Trimesh, spacing: float) -> np.ndarray:
    """Vertices plus points along the edges: ``(C, 3)``.

    An edge whose faces meet at angle ``a`` gets points every ``spacing / sin(a)`` mm (``a`` capped at
    90 deg, spacing capped at 2x): the depth an edge-edge contact can reach between two samples scales
    with the slope of the faces off the edge, so a shallow edge of a tessellated cylinder needs fewer
    points than a sharp one. Flat edges (triangulation diagonals) get none: a contact there is an
    edge-face contact, caught by the other part's points.
    """
    nv = len(mesh.vertices)
    adjacent = np.sort(mesh.face_adjacency_edges, axis=1)
    boundary = mesh.edges_unique[~np.isin(mesh.edges_unique @ [nv, 1], adjacent @ [nv, 1])]
    edge_vertices = np.concatenate([adjacent, boundary])
    angle = np.concatenate([mesh.face_adjacency_angles, np.full(len(boundary), np.pi / 2.0)])
    keep = angle > 1e-3
    edges = mesh.vertices[edge_vertices[keep]]  # (E, 2, 3)
    step = spacing / np.maximum(np.sin(np.minimum(angle[keep], np.pi / 2.0)), 0.5)
    n_inner = np.ceil(np.linalg.norm(edges[:, 1] - edges[:, 0], axis=1) / step).astype(np.int64) - 1
    n_inner = np.maximum(n_inner, 0)
    edge_id = np.repeat(np.arange(len(edges)), n_inner)
    # the k-th inner point of an edge with n inner points sits at fraction k / (n + 1)
    k = np.arange(len(edge_id)) - np.repeat(np.cumsum(n_inner) - n_inner, n_inner) + 1
    frac = (k / (n_inner[edge_id] + 1))[:, None]
    inner = edges[edge_id, 0] * (1.0 - frac) + edges[edge_id, 1] * frac
    return np.concatenate([np.asarray(mesh.vertices, dtype=np.float64), inner])


class _PlacedScene:
    """The static geometry a part can land on, in world frame: carrier first, then placed parts."""

    def __init__(self, carrier_world: trimesh.Trimesh, edge_spacing_mm: float) -> None:
        self.meshes: list[trimesh.Trimesh] = [carrier_world]
        self.check_points: list[np.ndarray] = [_contact_points(carrier_world, edge_spacing_mm)]
        self.contact_points = self.check_points[0]
        self.combined = carrier_world

    @property
    def top_z(self) -> float:
        return float(self.combined.bounds[1, 2])

    def add(self, mesh_world: trimesh.Trimesh, data: _MeshData, T_world_model: np.ndarray) -> None:
        self.meshes.append(mesh_world)
        self.check_points.append(transform_points(T_world_model, data.check_points))
        self.contact_points = np.concatenate(
            [self.contact_points, transform_points(T_world_model, data.contact_points)]
        )
        self.combined = trimesh.util.concatenate(self.meshes)


def _try_drop(
    data: _MeshData,
    scene: _PlacedScene,
    centre_xy: np.ndarray,
    spread: float,
    rng: np.random.Generator,
    max_penetration_mm: float,
) -> np.ndarray | None:
    """One attempt: random rest pose, yaw and xy, dropped to first contact; ``T_world_model`` or None."""
    rest = data.rest_poses[rng.choice(len(data.rest_probs), p=data.rest_probs)]
    yaw = make_pose(axis_angle_to_rotmat(np.array([0.0, 0.0, 1.0]), rng.uniform(0.0, 2.0 * np.pi)), np.zeros(3))
    T = compose(yaw, rest)
    local = transform_points(T, data.contact_points)
    lo, hi = local.min(axis=0), local.max(axis=0)
    carrier_lo, carrier_hi = scene.meshes[0].bounds
    # the part's xy box must stay within the carrier's footprint: its centre within [c_lo, c_hi]
    half = (hi[:2] - lo[:2]) / 2.0
    c_lo, c_hi = carrier_lo[:2] + half, carrier_hi[:2] - half
    target_xy = _draw_in_disk_and_box(centre_xy, spread, c_lo, c_hi, rng)
    shift = np.array([*(target_xy - (lo[:2] + hi[:2]) / 2.0), scene.top_z + _DROP_CLEARANCE_MM - lo[2]])
    T = compose(make_pose(np.eye(3), shift), T)

    moving_mesh = data.mesh.copy().apply_transform(T)
    drop = _drop_distance(local + shift, moving_mesh, scene)
    if not np.isfinite(drop):
        return None  # nothing below: it would fall past the carrier
    T = compose(make_pose(np.eye(3), np.array([0.0, 0.0, -drop])), T)
    moving_mesh.apply_translation([0.0, 0.0, -drop])
    if _max_penetration(moving_mesh, transform_points(T, data.check_points), scene) > max_penetration_mm:
        return None
    return T


def _drop_distance(moving_points: np.ndarray, moving_mesh: trimesh.Trimesh, scene: _PlacedScene) -> float:
    """How far (mm) the moving part falls along -z before it first touches the scene; inf if never."""
    down = _vertical_hit_distance(scene.combined, moving_points, -1.0)
    lo, hi = moving_mesh.bounds
    pts = scene.contact_points
    below = np.all((pts[:, :2] >= lo[:2]) & (pts[:, :2] <= hi[:2]), axis=1)
    up = _vertical_hit_distance(moving_mesh, pts[below], 1.0)
    return float(min(down.min(initial=np.inf), up.min(initial=np.inf)))


def _vertical_hit_distance(mesh: trimesh.Trimesh, origins: np.ndarray, sign: float) -> np.ndarray:
    """Distance ``(N,)`` along ``sign * z`` from each origin to its first hit on ``mesh`` (inf: no hit).

    Embree finds the triangle; the distance is recomputed in float64 from the triangle's plane.
    """
    dist = np.full(len(origins), np.inf)
    if len(origins) == 0:
        return dist
    directions = np.zeros_like(origins)
    directions[:, 2] = sign
    tri = mesh.ray.intersects_first(origins, directions)
    hit = np.flatnonzero(tri >= 0)
    n = mesh.face_normals[tri[hit]]
    p0 = mesh.triangles[tri[hit], 0]
    o = origins[hit]
    ok = np.abs(n[:, 2]) > 1e-9  # grazing a vertical face: that contact is an edge's, found by other rays
    nz = np.where(ok, n[:, 2], 1.0)
    z_plane = p0[:, 2] - (n[:, 0] * (o[:, 0] - p0[:, 0]) + n[:, 1] * (o[:, 1] - p0[:, 1])) / nz
    dist[hit[ok]] = np.maximum(sign * (z_plane[ok] - o[ok, 2]), 0.0)
    return dist


def _max_penetration(moving_mesh: trimesh.Trimesh, moving_points: np.ndarray, scene: _PlacedScene) -> float:
    """Deepest overlap (mm) between the moving part and any placed mesh whose bounds meet its bounds.

    Checks both ways: the moving part's points inside each neighbour and each neighbour's points
    inside the moving part. A mesh that is not watertight (an open carrier) is probed from the other side only.
    """
    lo, hi = moving_mesh.bounds
    depth = 0.0
    for mesh, points in zip(scene.meshes, scene.check_points, strict=True):
        other_lo, other_hi = mesh.bounds
        if np.any(other_lo > hi) or np.any(other_hi < lo):
            continue
        if mesh.is_watertight:
            depth = max(depth, penetration_depth(mesh, moving_points))
        if moving_mesh.is_watertight:
            depth = max(depth, penetration_depth(moving_mesh, points))
    return depth


def _draw_in_disk_and_box(
    centre: np.ndarray, radius: float, box_lo: np.ndarray, box_hi: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """A point ``(2,)`` uniform in the disk ``(centre, radius)`` and inside the box, by rejection.

    Falls back to the disk point clamped into the box (or the box centre if the box is empty) so that a
    big part on a small carrier still gets a position: a fixed number of draws keeps it deterministic.
    """
    n = 64
    r = radius * np.sqrt(rng.uniform(size=n))
    a = rng.uniform(0.0, 2.0 * np.pi, size=n)
    points = centre + np.stack([r * np.cos(a), r * np.sin(a)], axis=1)
    inside = np.all((points >= box_lo) & (points <= box_hi), axis=1)
    if inside.any():
        return points[np.argmax(inside)]
    if np.any(box_lo > box_hi):
        return (box_lo + box_hi) / 2.0
    return np.clip(points[0], box_lo, box_hi)
