"""Near-plane clipping of camera-space triangles, vectorised.

Triangles that cross the plane ``z = near`` are cut in 3D into one or two triangles with every vertex at
``z >= near``, so that nothing behind (or at) the camera is projected and no division by ``z <= 0`` can
produce inf or NaN. The cut keeps the winding, so the pieces face the same way as their parent. A new
vertex on an edge is computed from the edge's endpoints in a canonical order (lower vertex id first)
and gets an id derived from the edge, so two faces sharing a clipped edge get bit-identical points and
the rasterizer's shared-edge tie rule still holds there.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class ClippedTriangles:
    """Pieces of clipped triangles.

    Attributes:
        corners: ``(P, 3, 3)`` camera-space corners (piece, corner, xyz), all with ``z >= near``.
        vertex_ids: ``(P, 3)`` int64 ids for the canonical edge order; new vertices get consecutive ids
            above any mesh vertex id (one per cut edge).
        parent: ``(P,)`` int64 row of the input triangle each piece comes from.
    """

    corners: torch.Tensor
    vertex_ids: torch.Tensor
    parent: torch.Tensor


def clip_near(corners: torch.Tensor, vertex_ids: torch.Tensor, near: float, num_vertices: int) -> ClippedTriangles:
    """Clip triangles that straddle ``z = near`` against that plane.

    Args:
        corners: ``(T, 3, 3)`` camera-space corners; each triangle has at least one corner with
            ``z >= near`` and at least one with ``z < near``.
        vertex_ids: ``(T, 3)`` int64 mesh vertex ids of the corners.
        near: the near plane (mm, > 0).
        num_vertices: number of mesh vertices (new ids start above it).

    Returns:
        One piece per triangle with one corner in front, two pieces per triangle with two.
    """
    device = corners.device
    inside = corners[..., 2] >= near
    one_inside = inside.sum(1) == 1
    # Rotate each triangle (keeping its winding) so that its odd corner comes first: the one inside
    # when only one is inside, else the one outside.
    odd = inside == one_inside[:, None]
    first = odd.to(torch.int64).argmax(1)
    perm = (first[:, None] + torch.arange(3, device=device)) % 3
    rotated = corners.gather(1, perm[..., None].expand(-1, -1, 3))
    ids = vertex_ids.gather(1, perm)
    o, p, q = rotated[:, 0], rotated[:, 1], rotated[:, 2]
    o_id, p_id, q_id = ids[:, 0], ids[:, 1], ids[:, 2]
    op, op_id = _cut(o, p, o_id, p_id, near, num_vertices)
    oq, oq_id = _cut(o, q, o_id, q_id, near, num_vertices)

    rows = torch.arange(corners.shape[0], device=device)
    one = one_inside.nonzero().squeeze(1)
    two = (~one_inside).nonzero().squeeze(1)
    # One corner inside: (o, op, oq). Two inside (o outside): the quad p, q, oq, op as two triangles.
    pieces = [
        (torch.stack([o, op, oq], 1)[one], torch.stack([o_id, op_id, oq_id], 1)[one], rows[one]),
        (torch.stack([p, q, oq], 1)[two], torch.stack([p_id, q_id, oq_id], 1)[two], rows[two]),
        (torch.stack([p, oq, op], 1)[two], torch.stack([p_id, oq_id, op_id], 1)[two], rows[two]),
    ]
    ids = torch.cat([i for _, i, _ in pieces])
    new = ids >= num_vertices
    # Compact the edge-derived ids (up to N^2) to N, N + 1, ... so they stay exact in float32.
    _, compact = torch.unique(ids[new], return_inverse=True)
    ids[new] = num_vertices + compact
    return ClippedTriangles(
        corners=torch.cat([c for c, _, _ in pieces]),
        vertex_ids=ids,
        parent=torch.cat([r for _, _, r in pieces]),
    )


def _cut(
    a: torch.Tensor, b: torch.Tensor, a_id: torch.Tensor, b_id: torch.Tensor, near: float, num_vertices: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Point ``(T, 3)`` where edge a-b meets ``z = near`` (only meaningful where it does) and its id."""
    swap = (a_id > b_id)[:, None]
    lo, hi = torch.where(swap, b, a), torch.where(swap, a, b)
    dz = hi[:, 2] - lo[:, 2]
    safe = torch.where(dz == 0, torch.ones_like(dz), dz)
    t = ((near - lo[:, 2]) / safe).clamp(0.0, 1.0)
    point = lo + t[:, None] * (hi - lo)
    point = torch.cat([point[:, :2], torch.full_like(point[:, 2:], near)], 1)
    lo_id, hi_id = torch.minimum(a_id, b_id), torch.maximum(a_id, b_id)
    return point, num_vertices + lo_id * num_vertices + hi_id
