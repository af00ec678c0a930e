"""Meshes prepared for the rasterizer: float32 tensors, per-corner normals smoothed within a crease angle.

Why per-corner normals: a CAD tessellation of a curved surface (a shaft, a tube, a hole wall) must shade
smoothly, or its facets become false edges in the curvature map, while flat faces and sharp creases must
stay sharp (docs/design.md, "The renderer"). Each face corner gets the angle-weighted mean of the normals of
the faces around its vertex whose normal is within ``crease_angle_deg`` of the corner's own face normal.
Storing the normal per corner ``(F, 3, 3)`` is the same as splitting vertices at creases, without
re-indexing: the rasterizer interpolates corner normals perspective-correctly across each face.

Several meshes rendered together (a pile, a scene) are packed into one :class:`PackedMeshes` with an
instance id per face, so that one z-buffer pass resolves occlusion between them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
import torch

if TYPE_CHECKING:
    import trimesh


@dataclass(frozen=True, eq=False)
class RenderMesh:
    """A triangle mesh ready for rendering (model frame, mm).

    Attributes:
        vertices: ``(N, 3)`` float32 vertex positions.
        faces: ``(F, 3)`` int64 vertex indices, counter-clockwise seen from outside (outward normals).
        corner_normals: ``(F, 3, 3)`` float32 unit normal of each face corner (face, corner, xyz),
            smoothed within ``crease_angle_deg``.
        face_planes: ``(F, 4)`` float32 unit face normal n (from the vertices, 0 for degenerate faces)
            and ``n . v0``: per-mesh data for back-face culling without touching the vertices.
        radius: radius of the bounding sphere about the model origin, ``max |v|`` (mm); windows use it.
        crease_angle_deg: the crease angle the normals were smoothed with.
    """

    vertices: torch.Tensor
    faces: torch.Tensor
    corner_normals: torch.Tensor
    face_planes: torch.Tensor
    radius: float
    crease_angle_deg: float = 30.0

    @property
    def device(self) -> torch.device:
        return self.vertices.device

    @property
    def num_faces(self) -> int:
        return int(self.faces.shape[0])

    def to(self, device: torch.device | str) -> RenderMesh:
        """The same mesh with its tensors on ``device``."""
        return replace(
            self,
            vertices=self.vertices.to(device),
            faces=self.faces.to(device),
            corner_normals=self.corner_normals.to(device),
            face_planes=self.face_planes.to(device),
        )


@dataclass(frozen=True, eq=False)
class PackedMeshes:
    """Several meshes concatenated into one, for rendering them together with one z-buffer.

    Attributes:
        vertices: ``(N, 3)`` float32, all meshes' vertices, mesh after mesh.
        faces: ``(F, 3)`` int64 indices into the packed ``vertices``.
        corner_normals: ``(F, 3, 3)`` float32.
        face_planes: ``(F, 4)`` float32 (see :class:`RenderMesh`).
        vertex_instance: ``(N,)`` int64 index of the mesh each vertex belongs to.
        face_instance: ``(F,)`` int64 index of the mesh each face belongs to.
        face_local: ``(F,)`` int64 index of each face within its own mesh.
        radii: ``(M,)`` float32 bounding-sphere radius of each mesh about its origin.
        vertex_counts: each mesh's number of vertices, on the host (None: count them from ``vertex_instance``, a
            wait for the device where the meshes are on a GPU).
    """

    vertices: torch.Tensor
    faces: torch.Tensor
    corner_normals: torch.Tensor
    face_planes: torch.Tensor
    vertex_instance: torch.Tensor
    face_instance: torch.Tensor
    face_local: torch.Tensor
    radii: torch.Tensor
    vertex_counts: tuple[int, ...] | None = None

    @property
    def num_meshes(self) -> int:
        return int(self.radii.shape[0])

    @property
    def device(self) -> torch.device:
        return self.vertices.device


def prepare_mesh(
    mesh: trimesh.Trimesh, crease_angle_deg: float = 30.0, device: torch.device | str | None = None
) -> RenderMesh:
    """Convert a trimesh to a :class:`RenderMesh` with crease-aware smooth corner normals.

    Vertices at the same position are treated as one vertex for smoothing (PLY files often repeat
    them per face), but positions are kept exactly as given.

    Args:
        mesh: triangle mesh in mm, outward-facing (counter-clockwise) faces.
        crease_angle_deg: faces meeting at a vertex are smoothed together when their normals differ by
            at most this angle; 0 gives flat shading.
        device: where the tensors live (default CPU).

    Returns:
        The prepared mesh.
    """
    vertices = np.array(mesh.vertices, dtype=np.float64)  # a writable copy (trimesh's may be read-only)
    faces = np.array(mesh.faces, dtype=np.int64)
    corner_normals = crease_corner_normals(vertices, faces, crease_angle_deg)
    face_planes = face_planes_of(vertices, faces)
    radius = float(np.sqrt((vertices**2).sum(axis=1)).max()) if len(vertices) else 0.0
    return RenderMesh(
        vertices=torch.as_tensor(vertices, dtype=torch.float32, device=device),
        faces=torch.as_tensor(faces, dtype=torch.int64, device=device),
        corner_normals=torch.as_tensor(corner_normals, dtype=torch.float32, device=device),
        face_planes=torch.as_tensor(face_planes, dtype=torch.float32, device=device),
        radius=radius,
        crease_angle_deg=float(crease_angle_deg),
    )


def pack_meshes(meshes: Sequence[RenderMesh]) -> PackedMeshes:
    """Concatenate meshes (all on one device) into one :class:`PackedMeshes`, in the given order."""
    if not meshes:
        raise ValueError("pack_meshes needs at least one mesh")
    device = meshes[0].device
    n_vert = torch.tensor([m.vertices.shape[0] for m in meshes], device=device)
    n_face = torch.tensor([m.faces.shape[0] for m in meshes], device=device)
    vert_start = torch.cumsum(n_vert, 0) - n_vert
    ids = torch.arange(len(meshes), device=device)
    face_instance = torch.repeat_interleave(ids, n_face)
    faces = torch.cat([m.faces for m in meshes]) + vert_start[face_instance, None]
    face_start = torch.cumsum(n_face, 0) - n_face
    return PackedMeshes(
        vertices=torch.cat([m.vertices for m in meshes]),
        faces=faces,
        corner_normals=torch.cat([m.corner_normals for m in meshes]),
        face_planes=torch.cat([m.face_planes for m in meshes]),
        vertex_instance=torch.repeat_interleave(ids, n_vert),
        face_instance=face_instance,
        face_local=torch.arange(faces.shape[0], device=device) - face_start[face_instance],
        radii=torch.tensor([m.radius for m in meshes], dtype=torch.float32, device=device),
        vertex_counts=tuple(int(m.vertices.shape[0]) for m in meshes),
    )


def crease_corner_normals(vertices: np.ndarray, faces: np.ndarray, crease_angle_deg: float) -> np.ndarray:
    """Per-corner unit normals ``(F, 3, 3)`` smoothed within a crease angle (vectorised, float64).

    The normal of corner (f, k) at vertex position p is the normalised sum, over the faces g around p
    whose unit normal satisfies ``n_g . n_f >= cos(crease)``, of ``angle_g(p) * n_g``, where
    ``angle_g(p)`` is g's interior angle at p (angle weighting is insensitive to how a CAD exporter
    splits a surface into thin triangles). Degenerate (zero-area) faces have a zero normal: they never
    contribute, and their own corner normals are zero (the rasterizer never draws them).

    Args:
        vertices: ``(N, 3)`` positions.
        faces: ``(F, 3)`` vertex indices.
        crease_angle_deg: smoothing threshold in degrees.

    Returns:
        ``(F, 3, 3)`` float64 corner normals (zero only for isolated degenerate faces).
    """
    n_faces = faces.shape[0]
    if n_faces == 0:
        return np.zeros((0, 3, 3))
    tri = vertices[faces]  # (F, 3, 3)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=1, keepdims=True)
    face_normals = np.divide(cross, norm, out=np.zeros_like(cross), where=norm > 0)
    angles = _corner_angles(tri)  # (F, 3)

    # Vertices at equal positions count as one (PLY files may repeat them per face).
    _, group = np.unique(vertices, axis=0, return_inverse=True)
    corner_group = group.reshape(-1)[faces.reshape(-1)]  # (3F,)
    corner_face = np.repeat(np.arange(n_faces), 3)
    order = np.argsort(corner_group, kind="stable")
    sorted_group = corner_group[order]
    starts = np.searchsorted(sorted_group, sorted_group, side="left")
    sizes = np.searchsorted(sorted_group, sorted_group, side="right") - starts
    # Every ordered pair (corner, other corner at the same position): sum of valence^2 pairs.
    first = np.repeat(order, sizes)
    rank = np.arange(first.shape[0]) - np.repeat(np.cumsum(sizes) - sizes, sizes)
    second = order[np.repeat(starts, sizes) + rank]
    f1, f2 = corner_face[first], corner_face[second]
    cos_limit = math.cos(math.radians(crease_angle_deg))
    keep = (np.einsum("ij,ij->i", face_normals[f1], face_normals[f2]) >= cos_limit - 1e-12) | (f1 == f2)
    first, f2, second = first[keep], f2[keep], second[keep]
    weights = angles.reshape(-1)[second][:, None] * face_normals[f2]
    summed = np.stack([np.bincount(first, weights=weights[:, k], minlength=3 * n_faces) for k in range(3)], axis=1)
    norm = np.linalg.norm(summed, axis=1, keepdims=True)
    fallback = np.repeat(face_normals, 3, axis=0)
    out = np.where(norm > 1e-12, summed / np.maximum(norm, 1e-300), fallback)
    return out.reshape(n_faces, 3, 3)


def face_planes_of(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(F, 4)``: unit normal (0 for degenerate faces) and its dot with the first corner."""
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=1, keepdims=True)
    unit = np.divide(cross, norm, out=np.zeros_like(cross), where=norm > 0)
    return np.concatenate([unit, np.einsum("ij,ij->i", unit, tri[:, 0])[:, None]], axis=1)


def _corner_angles(tri: np.ndarray) -> np.ndarray:
    """Interior angles ``(F, 3)`` of triangles ``(F, 3, 3)`` at each corner (0 for degenerate ones)."""
    angles = np.zeros(tri.shape[:2])
    for k in range(3):
        a = tri[:, (k + 1) % 3] - tri[:, k]
        b = tri[:, (k + 2) % 3] - tri[:, k]
        cos = np.einsum("ij,ij->i", a, b)
        sin = np.linalg.norm(np.cross(a, b), axis=1)
        angles[:, k] = np.arctan2(sin, cos)
    return angles
