"""Exact triangle rasterisation into windows, batched over canvases, in PyTorch ("TriSpan").

A *canvas* is one (pose, camera) pair. Each canvas is rendered only inside its own window
(:class:`~bop_cender.render.window.Windows`): a block of image rows and columns whose first pixel is
``(v0, u0)`` (row, column) of the full image; the full frame is the window at (0, 0) of the image's
size. Window pixels beyond the image border are rendered like any other pixel (as if the image went
on).

Conventions (docs/design.md, "The pixel convention"): camera x right, y down, z forward; pixel (u, v) is
covered iff the continuous point (u + 0.5, v + 0.5) is inside the projected triangle; its depth is the z
of the ray through that point. Ties follow the top-left rule (see :mod:`bop_cender.render.scanline`), so
faces that share an edge split its pixels with no holes and no double coverage.

The pipeline, vectorised, with no Python loop over faces or pixels:

1. Camera-space vertices and their projections, once per (canvas, vertex).
2. Cull per (canvas, face), from per-mesh face planes: back faces and faces seen edge-on
   (``n . X0 > -1e-3`` mm in the camera frame), faces entirely behind the near plane. Faces crossing the near plane are cut in 3D
   (:mod:`bop_cender.render.clip`) so nothing behind the camera is drawn and nothing divides by 0.
3. Per drawn face, a 12-float shading row: ``M (3x3)`` with ``normal(p) ~ M @ (x, y, 1)`` (the
   perspective-correct interpolation of the camera-space corner normals, exact up to the final
   normalisation) and ``(a, b, c)`` with ``1/z = a x + b y + c``, both from the face's 3D corners
   (homogeneous barycentrics: ``lambda_i / z = (X_j x X_k) . K^-1 p / det(X0, X1, X2)``).
4. Scanline expansion to fragments and ONE ``scatter_reduce_(amax)`` of packed keys per window pixel
   (:mod:`bop_cender.render.scanline`): the nearest fragment (largest 1/z) wins, ties to the larger
   face id, deterministically.

Work follows covered pixels plus rows, not image area times faces.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from bop_cender.render.clip import clip_near
from bop_cender.render.mesh import PackedMeshes, RenderMesh
from bop_cender.render.scanline import KeyCodec, scan, winners
from bop_cender.render.settings import DEFAULT_RENDER_SETTINGS
from bop_cender.render.window import Windows

#: Default near plane (mm): geometry closer than this to the camera plane is clipped away.
DEFAULT_NEAR = DEFAULT_RENDER_SETTINGS.near

#: Faces whose plane passes closer than this to the camera centre (mm) are seen edge-on: not drawn.
_EDGE_ON = 1e-3


@dataclass(frozen=True)
class Raster:
    """The z-buffer of a batch of canvases and its covered pixels, before shading.

    Attributes:
        windows: where each canvas's window is (image and buffer).
        keys: ``(total,)`` winning key per buffer pixel (int32 or int64, negative on background).
        codec: how keys pack depth and face id.
        table: ``(12, T + 1)`` float32 shading column per drawn (canvas, face): ``M`` row-major (9),
            then the ``1/z`` plane (3); the last column is zeros. Stored channel by channel, so that
            each of the 12 can be gathered as one contiguous row.
        face_canvas: ``(T,)`` int64 canvas of each table row.
        face_index: ``(T,)`` int64 mesh face of each table row.
        pix: ``(P,)`` int64 buffer index of each covered pixel.
        pix_row: ``(P,)`` int32 table row of the face that won it.
        pix_x, pix_y: ``(P,)`` float32 its centre in image coordinates, ``(u + 0.5, v + 0.5)``.
    """

    windows: Windows
    keys: torch.Tensor
    codec: KeyCodec
    table: torch.Tensor
    face_canvas: torch.Tensor
    face_index: torch.Tensor
    pix: torch.Tensor
    pix_row: torch.Tensor
    pix_x: torch.Tensor
    pix_y: torch.Tensor


def rasterize(
    mesh: RenderMesh | PackedMeshes,
    R: torch.Tensor,
    t: torch.Tensor,
    K: torch.Tensor,
    windows: Windows,
    near: float = DEFAULT_NEAR,
    verts: torch.Tensor | None = None,
    normals: bool = True,
) -> Raster:
    """Rasterise a mesh (or packed meshes) into one window per canvas.

    Args:
        mesh: a :class:`~bop_cender.render.mesh.RenderMesh` or
            :class:`~bop_cender.render.mesh.PackedMeshes` (instances: its meshes), on R's device.
        R: ``(C, I, 3, 3)`` float32 model-to-camera rotation of each instance in each canvas.
        t: ``(C, I, 3)`` float32 model-to-camera translation (mm).
        K: ``(C, 3, 3)`` float32 intrinsics per canvas.
        windows: the canvases' windows.
        near: near plane (mm, > 0).
        verts: ``(3, C, N)`` camera-space vertices if already computed (:func:`camera_vertices`).
        normals: fill the table's normal rows; False leaves them 0 (depth and face ids only, ~10 % faster).

    Returns:
        The z-buffer, its covered pixels and the table to shade them with
        (:func:`bop_cender.render.resolve.resolve`).
    """
    device, dtype = R.device, R.dtype
    C, N, F = int(R.shape[0]), int(mesh.vertices.shape[0]), int(mesh.faces.shape[0])
    face_instance = getattr(mesh, "face_instance", None)
    codec = KeyCodec.for_faces(F, exact=face_instance is not None)
    keys = torch.full((windows.total,), -1, dtype=codec.dtype, device=device)
    empty = Raster(
        windows,
        keys,
        codec,
        torch.zeros(12, 1, dtype=dtype, device=device),
        *(torch.zeros(0, dtype=torch.int64, device=device),) * 3,
        torch.zeros(0, dtype=torch.int32, device=device),
        *(torch.zeros(0, dtype=dtype, device=device),) * 2,
    )
    if C == 0 or F == 0:
        return empty

    # 1. Camera-space vertices, structure of arrays (3, C, N), and their projections (C, N).
    if verts is None:
        verts = camera_vertices(mesh, R, t)
    z = verts[2]
    all_in_front = bool(z.amin() >= near)
    px, py = project_vertices(verts, K, near)

    # 2. Cull back faces and faces seen edge-on.
    draw = front_faces(mesh, R, t)
    if not all_in_front:
        behind = (z < near).reshape(-1)
        corner_behind = behind[(torch.arange(C, device=device)[:, None, None] * N + mesh.faces).reshape(-1)]
        n_behind = corner_behind.view(C, F, 3).sum(-1)
        draw &= n_behind < 3
    face_canvas, face_index = draw.nonzero(as_tuple=True)
    T = face_canvas.numel()
    if T == 0:
        return empty

    # 3. Shading table from the drawn faces' camera-space corners (structure of arrays: (T,) each).
    faces_soa = mesh.faces.T.contiguous()
    vid = [faces_soa[i].index_select(0, face_index) for i in range(3)]
    flat = [face_canvas * N + v for v in vid]
    coords = [verts[a].reshape(-1) for a in range(3)]
    corners = [[coords[a].index_select(0, f) for a in range(3)] for f in flat]
    inst = face_canvas if face_instance is None else face_canvas * R.shape[1] + face_instance[face_index]
    K_inv = _rows(torch.linalg.inv(K.double()).to(dtype).reshape(-1, 9), face_canvas)
    if normals:
        rot = _rows(R.reshape(-1, 9), inst)  # row-major R
        normals_model = _rows(mesh.corner_normals.reshape(-1, 9), face_index)  # 3 i + a: corner i, axis a
        table = _face_table(corners, K_inv, normals_model, rot)
    else:
        table = _face_table(corners, K_inv)

    # 4. Screen triangles, corner-major (3, S): regular faces, plus the pieces of faces cut by the near plane.
    tri_x = torch.stack([px.reshape(-1).index_select(0, f) for f in flat])
    tri_y = torch.stack([py.reshape(-1).index_select(0, f) for f in flat])
    tri_row = torch.arange(T, device=device)
    vid = torch.stack(vid).to(torch.int32)
    if not all_in_front:
        on_face = n_behind[face_canvas, face_index]
        crossing, regular = (on_face > 0).nonzero().squeeze(1), (on_face == 0).nonzero().squeeze(1)
        cut = torch.stack([torch.stack(c).index_select(1, crossing).T for c in corners], 1)  # (Tc, 3, 3)
        pieces = clip_near(cut, vid.T.index_select(0, crossing).to(torch.int64), near, N)
        parent = crossing[pieces.parent]
        piece_x, piece_y = project_vertices(
            pieces.corners.permute(2, 0, 1), K.index_select(0, face_canvas[parent]), near
        )
        tri_x = torch.cat([tri_x.index_select(1, regular), piece_x.T], 1)
        tri_y = torch.cat([tri_y.index_select(1, regular), piece_y.T], 1)
        vid = torch.cat([vid.index_select(1, regular), pieces.vertex_ids.T.to(torch.int32)], 1)
        tri_row = torch.cat([regular, parent])
    tri_canvas = face_canvas.index_select(0, tri_row)
    depth_planes = codec.depth_planes(table[9:, :-1], z, near, face_canvas)
    fragments = scan(
        tri_x,
        tri_y,
        vid,
        face_index.to(torch.int32).index_select(0, tri_row),
        depth_planes.index_select(1, tri_row),
        torch.stack(_rows(windows.table(), tri_canvas)),
        windows.width,
        codec,
    )
    keys.scatter_reduce_(0, fragments.lin, fragments.key, reduce="amax")
    pix, tri, x, y = winners(fragments, keys)
    return Raster(
        windows,
        keys,
        codec,
        table,
        face_canvas,
        face_index,
        pix,
        tri_row.to(torch.int32).index_select(0, tri),
        x,
        y,
    )


def front_faces(mesh: RenderMesh | PackedMeshes, R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """``(C, F)`` bool: the faces drawn in each canvas, neither back faces nor seen edge-on (their plane closer than
    ``_EDGE_ON`` mm to the camera centre). ``n . X0 = n . x0 + n . (R^T t)`` is the signed distance from the
    camera to the face's plane. ``R (C, I, 3, 3)``, ``t (C, I, 3)`` as :func:`rasterize` takes them."""
    tau = torch.einsum("cimj,cim->cij", R, t)  # (C, I, 3): R^T t per instance
    planes = mesh.face_planes
    face_instance = getattr(mesh, "face_instance", None)
    if face_instance is None:
        facing = torch.addmm(planes[:, 3], tau[:, 0], planes[:, :3].T)  # (C, F)
    else:
        facing = (tau[:, face_instance] * planes[:, :3]).sum(-1) + planes[:, 3]
    return facing < -_EDGE_ON


def camera_vertices(mesh: RenderMesh | PackedMeshes, R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Camera-space vertices ``(3, C, N)`` (axis, canvas, vertex) of a mesh or packed meshes.

    Args:
        mesh: :class:`~bop_cender.render.mesh.RenderMesh` or :class:`~bop_cender.render.mesh.PackedMeshes`.
        R: ``(C, I, 3, 3)`` rotations, ``t``: ``(C, I, 3)`` translations per instance.
    """
    vertex_instance = getattr(mesh, "vertex_instance", None)
    if vertex_instance is None:
        parts = [mesh.vertices]
    else:  # packed meshes are contiguous, instance after instance
        counts = mesh.vertex_counts
        if counts is None:  # counted on the device: a wait for it
            counts = torch.bincount(vertex_instance, minlength=R.shape[1]).tolist()
        parts = torch.split(mesh.vertices, list(counts))
    out = [torch.matmul(R[:, i], v.T) + t[:, i, :, None] for i, v in enumerate(parts)]  # (C, 3, n_i)
    return torch.cat(out, 2).transpose(0, 1).contiguous()


def _rows(table: torch.Tensor, index: torch.Tensor) -> list[torch.Tensor]:
    """Columns of a small ``(R, k)`` table gathered at ``index (T,)``: k contiguous ``(T,)`` tensors."""
    return [column.index_select(0, index) for column in table.T.contiguous()]


def project_vertices(points: torch.Tensor, K: torch.Tensor, near: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixel coordinates ``x, y (C, N)`` of camera-space points ``(3, C, N)`` under ``K (C, 3, 3)``.

    Depth is clamped to ``near`` so that points behind the camera give finite (unused) values.
    """
    inv_z = points[2].clamp_min(near).reciprocal_()
    x = (K[:, 0, 0, None] * points[0]).addcmul_(K[:, 0, 1, None], points[1]).mul_(inv_z).add_(K[:, 0, 2, None])
    y = (K[:, 1, 1, None] * points[1]).mul_(inv_z).add_(K[:, 1, 2, None])
    return x, y


def _face_table(
    corners: list[list[torch.Tensor]],
    K_inv: list[torch.Tensor],
    normals_model: list[torch.Tensor] | None = None,
    rot: list[torch.Tensor] | None = None,
) -> torch.Tensor:
    """Shading table ``(12, T + 1)``: one column per face (last column zeros), structure of arrays.

    Rows 0-8: ``M`` row-major with ``normal(p) ~ M @ (x, y, 1)``; rows 9-11: the ``1/z`` plane.
    With ``c_i = X_j x X_k`` and ``d = det(X0, X1, X2)``, ``lambda_i / z = c_i . K^-1 p / d`` (positive
    inside the triangle whichever way it faces), ``1/z = sum_i lambda_i / z`` and
    ``normal ~ sum_i (lambda_i / z) R n_i``.

    Args:
        corners: 3 corners, each 3 camera-space coordinates ``(T,)``.
        K_inv: 9 ``(T,)``: inverse intrinsics, row-major (upper triangular).
        normals_model: 9 ``(T,)``: model-frame corner normals, ``3 i + a`` = corner i, axis a; None
            leaves rows 0-8 zero (only depth wanted).
        rot: 9 ``(T,)``: model-to-camera rotation, row-major (with ``normals_model``).
    """
    x0, x1, x2 = corners
    e1, e2 = _sub(x1, x0), _sub(x2, x0)
    normal = _cross(e1, e2)
    inv_det = (x0[0] * normal[0]).addcmul_(x0[1], normal[1]).addcmul_(x0[2], normal[2]).reciprocal_()
    # Row vector c times the upper-triangular K^-1, over det: (c_x s00, c_x s01 + c_y s11, c_x s02 + c_y s12 + c_z s22).
    s00, s01, s02, s11, s12 = (K_inv[k] * inv_det for k in (0, 1, 2, 4, 5))

    def plane(c: list[torch.Tensor]) -> list[torch.Tensor]:
        return [c[0] * s00, (c[0] * s01).addcmul_(c[1], s11), (c[0] * s02).addcmul_(c[1], s12).addcmul_(c[2], inv_det)]

    table = torch.zeros((12, x0[0].shape[0] + 1), dtype=x0[0].dtype, device=x0[0].device)
    if normals_model is not None and rot is not None:
        bary = [_cross(x1, _sub(x2, x1)), _cross(e2, x2), _cross(x0, e1)]  # c_i = X_j x X_k
        planes = [plane(c) for c in bary]
        ncam = [
            [
                (rot[3 * a] * normals_model[3 * i])
                .addcmul_(rot[3 * a + 1], normals_model[3 * i + 1])
                .addcmul_(rot[3 * a + 2], normals_model[3 * i + 2])
                for a in range(3)
            ]
            for i in range(3)
        ]  # corner i, axis a
        for a in range(3):
            for k in range(3):
                torch.mul(ncam[0][a], planes[0][k], out=table[3 * a + k, :-1])
                table[3 * a + k, :-1].addcmul_(ncam[1][a], planes[1][k]).addcmul_(ncam[2][a], planes[2][k])
    for k, value in enumerate(plane(normal)):
        table[9 + k, :-1] = value
    return table


def _sub(a: list[torch.Tensor], b: list[torch.Tensor]) -> list[torch.Tensor]:
    return [a[k] - b[k] for k in range(3)]


def _cross(a: list[torch.Tensor], b: list[torch.Tensor]) -> list[torch.Tensor]:
    return [
        (a[1] * b[2]).sub_(a[2] * b[1]),
        (a[2] * b[0]).sub_(a[0] * b[2]),
        (a[0] * b[1]).sub_(a[1] * b[0]),
    ]
