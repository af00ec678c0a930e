"""A mesh's edges as the edge proxy of the cost sees them (model frame, mm): segments and their face planes.

Built once per object (:func:`edge_model_of`): every mesh edge cut into short segments, each edge's two face planes
and whether it is a crease, and the tables that place each segment on its edge (:class:`SegmentProjection`). What
the proxy computes from them is in :mod:`bop_cender.pose.edge_cost` (torch) and :mod:`bop_cender.pose.edge_kernel`
(numba, CPU and CUDA); the data lives here, below all of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from functools import cached_property

import numpy as np
import torch

from bop_cender.render.mesh import RenderMesh, face_planes_of

#: Edges whose faces' normals differ by more than this are creases (the renderer's default crease angle,
#: :func:`bop_cender.render.mesh.prepare_mesh`: smoother edges are shaded smoothly and draw no curvature).
DEFAULT_CREASE_ANGLE_DEG = 30.0


@dataclass(frozen=True, eq=False)
class EdgeModel:
    """A mesh's edges, cut into short segments, and what decides whether each is drawn (model frame, mm).

    Attributes:
        vertices: ``(N, 3)`` float32 segment end points (the mesh's distinct vertex positions, then the
            points that cut long edges).
        segments: ``(S, 2)`` int64 end points of each segment, edge after edge.
        planes: ``(E, 2, 4)`` float32 the two faces of each edge: unit normal and ``n . v``; a boundary
            edge (one face) repeats its face.
        crease: ``(E,)`` bool: drawn whenever one of its faces faces the camera (creases, boundaries);
            the other edges only where they are on the contour.
        edge_segments: ``(E, 2)`` int64 first segment and number of segments of each edge.
    """

    vertices: torch.Tensor
    segments: torch.Tensor
    planes: torch.Tensor
    crease: torch.Tensor
    edge_segments: torch.Tensor

    @property
    def device(self) -> torch.device:
        return self.vertices.device

    @cached_property
    def projection(self) -> SegmentProjection:
        """Tables that place every segment on its edge (built once per model; see :class:`SegmentProjection`)."""
        return SegmentProjection.of(self)

    @property
    def num_segments(self) -> int:
        return int(self.segments.shape[0])

    @property
    def num_edges(self) -> int:
        return int(self.crease.shape[0])

    def to(self, device: torch.device | str) -> EdgeModel:
        return EdgeModel(*(getattr(self, f.name).to(device) for f in fields(self)))

    def sparse(self, max_segments: int) -> EdgeModel:
        """A model of every k-th edge, with at most about ``max_segments`` segments: a cheaper proxy for
        ranking many candidates (the cost is a mean over the drawn points, so a uniform subset of the
        edges estimates it). Returns ``self`` when it is small enough already."""
        if self.num_segments <= max_segments:
            return self
        stride = -(-self.num_segments // max_segments)
        edges = torch.arange(0, self.num_edges, stride, device=self.device)
        first, count = self.edge_segments.index_select(0, edges).unbind(1)
        seg = torch.repeat_interleave(first, count) + ranks(count)
        ends = self.segments.index_select(0, seg)
        used, remap = torch.unique(ends, return_inverse=True)
        return EdgeModel(
            self.vertices.index_select(0, used),
            remap.view(-1, 2),
            self.planes.index_select(0, edges),
            self.crease.index_select(0, edges),
            torch.stack([torch.cumsum(count, 0) - count, count], 1),
        )


@dataclass(frozen=True, eq=False)
class SegmentProjection:
    """Every segment as a stretch ``[frac_a, frac_b]`` of its edge, whose ends are mesh vertices.

    Why: projecting every segment end (a part's cut points outnumber its vertices 10-40 times) was a quarter
    of a cost call. Homogeneous pixel coordinates ``K (R X + t)`` are linear in ``X``, so a segment end's are
    the lerp of its edge ends' at the segment's fraction along the edge (to float rounding; the perspective
    division comes after), and only the edge ends need a matrix product.

    Attributes:
        ends: ``(4, M)`` float32 the edges' end vertices as contiguous homogeneous columns.
        seg_from, seg_to: ``(S,)`` int64 column in ``ends`` of the start and end of each segment's edge.
        seg_edge: ``(S,)`` int64 edge of each segment.
        frac_a, frac_b: ``(S,)`` float32 where each segment starts and ends along its edge (0 at its start,
            1 at its end).
    """

    ends: torch.Tensor
    seg_from: torch.Tensor
    seg_to: torch.Tensor
    seg_edge: torch.Tensor
    frac_a: torch.Tensor
    frac_b: torch.Tensor

    @staticmethod
    def of(model: EdgeModel) -> SegmentProjection:
        """The tables of ``model``: each edge's segments are a straight chain of equal pieces from its first
        segment's start to its last segment's end (:func:`edge_model`; :meth:`EdgeModel.sparse` keeps whole edges)."""
        first, count = model.edge_segments.unbind(1)
        edge_from = model.segments[first, 0]
        edge_to = model.segments[first + count - 1, 1]
        used, column = torch.unique(torch.cat([edge_from, edge_to]), return_inverse=True)
        E = int(first.shape[0])
        seg_edge = torch.repeat_interleave(torch.arange(E, device=model.device), count)
        rank = ranks(count).double()
        pieces = count.double().index_select(0, seg_edge)
        vertices = model.vertices.index_select(0, used)
        ones = torch.ones((vertices.shape[0], 1), device=model.device, dtype=vertices.dtype)
        return SegmentProjection(
            ends=torch.cat([vertices, ones], 1).T.contiguous(),
            seg_from=column[:E].index_select(0, seg_edge),
            seg_to=column[E:].index_select(0, seg_edge),
            seg_edge=seg_edge,
            frac_a=(rank / pieces).float(),
            frac_b=((rank + 1) / pieces).float(),
        )


def edge_model(
    vertices: np.ndarray,
    faces: np.ndarray,
    segment_mm: float = 3.0,
    crease_angle_deg: float = DEFAULT_CREASE_ANGLE_DEG,
    device: torch.device | str | None = None,
) -> EdgeModel:
    """The edges of a triangle mesh ``vertices (N, 3)``, ``faces (F, 3)`` (mm, outward faces).

    Vertices at the same position are one vertex (PLY files often repeat them per face), so the faces
    of a closed mesh share edges. An edge longer than ``segment_mm`` is cut into ``ceil(length /
    segment_mm)`` equal segments, so that a segment's projection is short and
    :data:`SAMPLES_PER_SEGMENT` points cover it. Degenerate (zero-area) faces are left out.
    """
    if not (math.isfinite(segment_mm) and segment_mm > 0):
        raise ValueError(f"segment_mm must be a positive number, got {segment_mm}")
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    unique, same = np.unique(np.round(v, 6), axis=0, return_inverse=True)
    same = same.reshape(-1)
    merged = same[f]  # (F, 3) ids of distinct positions
    plane = face_planes_of(v, f)  # (F, 4): the renderer's face planes, a zero normal for a degenerate face
    keep = np.abs(plane[:, :3]).sum(1) > 0
    merged, plane = merged[keep], plane[keep]
    if len(merged) == 0:
        raise ValueError("the mesh has no face of non-zero area")
    # Position of each distinct vertex: the first original vertex at it (exact, not the rounded key).
    position = np.zeros((len(unique), 3))
    position[same[::-1]] = v[::-1]
    a = merged.reshape(-1)
    b = merged[:, [1, 2, 0]].reshape(-1)
    face = np.repeat(np.arange(len(merged)), 3)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    key = lo * len(unique) + hi
    order = np.argsort(key, kind="stable")
    key, face, lo, hi = key[order], face[order], lo[order], hi[order]
    first = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    count = np.diff(np.r_[first, len(key)])
    f1 = face[first]
    f2 = np.where(count >= 2, face[np.minimum(first + 1, len(key) - 1)], f1)
    cos = np.einsum("ij,ij->i", plane[f1, :3], plane[f2, :3])
    crease = (count < 2) | (cos < math.cos(math.radians(crease_angle_deg)))
    p, q = lo[first], hi[first]
    length = np.linalg.norm(position[q] - position[p], axis=1)
    pieces = np.maximum(1, np.ceil(length / segment_mm)).astype(np.int64)
    # Edge e becomes the chain p, its pieces[e] - 1 cut points (new vertices), q.
    n_edges = len(p)
    edge_of_cut = np.repeat(np.arange(n_edges), pieces - 1)
    cut_rank = np.arange(len(edge_of_cut)) - np.repeat(np.cumsum(pieces - 1) - (pieces - 1), pieces - 1)
    frac = (cut_rank + 1) / pieces[edge_of_cut]
    cuts = position[p[edge_of_cut]] + frac[:, None] * (position[q] - position[p])[edge_of_cut]
    chain_start = np.cumsum(pieces + 1) - (pieces + 1)
    chain = np.empty(int((pieces + 1).sum()), dtype=np.int64)
    chain[chain_start] = p
    chain[chain_start + pieces] = q
    chain[chain_start[edge_of_cut] + 1 + cut_rank] = len(position) + np.arange(len(cuts))
    seg_edge = np.repeat(np.arange(n_edges), pieces)
    seg_at = np.arange(len(seg_edge)) + seg_edge  # position of each segment's start in the chain
    start, end = chain[seg_at], chain[seg_at + 1]

    def tensor(x: np.ndarray, dtype: torch.dtype) -> torch.Tensor:
        return torch.as_tensor(np.ascontiguousarray(x), dtype=dtype, device=device)

    return EdgeModel(
        vertices=tensor(np.concatenate([position, cuts]), torch.float32),
        segments=tensor(np.stack([start, end], axis=1), torch.int64),
        planes=tensor(np.stack([plane[f1], plane[f2]], axis=1), torch.float32),
        crease=tensor(crease, torch.bool),
        edge_segments=tensor(np.stack([np.cumsum(pieces) - pieces, pieces], axis=1), torch.int64),
    )


def edge_model_of(mesh: RenderMesh, segment_mm: float = 3.0) -> EdgeModel:
    """:func:`edge_model` of a prepared render mesh, with its crease angle, on its device."""
    return edge_model(
        mesh.vertices.double().cpu().numpy(),
        mesh.faces.cpu().numpy(),
        segment_mm,
        mesh.crease_angle_deg,
        device=mesh.device,
    )


def ranks(count: torch.Tensor) -> torch.Tensor:
    """``0 .. count[i] - 1`` for each i, concatenated: ``(sum(count),)`` int64."""
    total = int(count.sum())
    starts = torch.repeat_interleave(torch.cumsum(count, 0) - count, count, output_size=total)
    return torch.arange(total, device=count.device) - starts
