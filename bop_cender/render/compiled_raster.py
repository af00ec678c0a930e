"""The torch rasteriser as one compiled loop per canvas (CPU): the same bits without its per-call operators.

Why. The torch renderer (:mod:`bop_cender.render.raster`, :mod:`bop_cender.render.scanline`,
:mod:`bop_cender.render.resolve`) is written for large batches: a call costs about 2,000 operators whatever its
size. Stage 3 renders in thousands of small calls (the scene polish: one part into 7 windows of about 140 x 140
pixels per Nelder-Mead step), where those operators were most of the time. Here the same pipeline runs as one
loop over each canvas's faces and pixels; :func:`~bop_cender.render.rasterizer.render_scene` and the one-mesh
window renders use it on the CPU by default.

Same rules and the same float32 arithmetic as the torch renderer, step for step: the vertices, projections and
culling are the torch functions' own (:func:`~bop_cender.render.raster.camera_vertices`,
:func:`~bop_cender.render.raster.project_vertices`, :func:`~bop_cender.render.raster.front_faces`); each face's
shading row (:func:`bop_cender.render.raster._face_table`) with torch's ``addcmul`` rounding (:func:`torch_fma`, as
probed: :data:`ADDCMUL_FUSED`); corners sorted by y, edges anchored at their end point of lower vertex id, the
top-left rule at pixel centres; int32 keys of ``1/z`` quantised over the canvas's depth range with the face id in
the low bits (larger key wins), or exact ``1/z`` with ties to the larger face id (packed meshes, large meshes);
normals and depth at the centres of the covered pixels. The maps are the torch pipeline's bit for bit
(``tests/render/test_compiled_raster.py``): bits matter, as stage 3's edge threshold (3.0) is exactly the
curvature of an axis-aligned silhouette step. Canvases with a vertex behind the near plane (cut there by the torch
renderer) are not rendered here: :func:`render_compiled` returns None and the caller uses the torch renderer.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

from bop_cender.render.mesh import PackedMeshes, RenderMesh
from bop_cender.render.numba_cache import cached_njit
from bop_cender.render.numba_loops import as_numpy as _np
from bop_cender.render.numba_loops import canvas_loop
from bop_cender.render.raster import DEFAULT_NEAR, camera_vertices, front_faces, project_vertices
from bop_cender.render.raster_arithmetic import TABLE_WIDTH, raster_arithmetic
from bop_cender.render.scanline import KeyCodec

_HALF = np.float32(0.5)


@canvas_loop(error_model="numpy")
def _render_canvases(cam_all, px_all, py_all, draw, faces, face_instance, corner_normals, R, K_inv, offsets, h, w,
                     near, face_bits, depth_bits, fused, depth, normals, face_map):  # fmt: skip
    """Depth ``(C, h, w)``, normals ``(C, h, w, 3)`` (zeroed by the caller) and face ids ``(C, h, w)`` (-1 by the
    caller) of a mesh or packed meshes in C canvases, each in its window at ``offsets[c]`` (row, column)."""
    for c in numba.prange(R.shape[0]):
        raster_window(cam_all[c], px_all[c], py_all[c], draw[c], faces, face_instance, corner_normals, R[c], K_inv[c],
                      offsets[c, 0], offsets[c, 1], h, w, near, face_bits, depth_bits, fused, depth[c], normals[c],
                      face_map[c])  # fmt: skip
    return 0


@cached_njit(nogil=True, error_model="numpy")
def raster_window(cam, px, py, draw, faces, face_instance, corner_normals, R, K_inv, v0, u0, h, w, near, face_bits,
                  depth_bits, fused, depth_out, normals_out, face_out):  # fmt: skip
    """Render one canvas into its window: rows ``v0 .. v0 + h - 1`` and columns ``u0 .. u0 + w - 1`` of the image.

    Args:
        cam: ``(N, 3)`` float32 camera-space vertices; px, py: ``(N,)`` their projections
            (:func:`~bop_cender.render.raster.project_vertices`).
        draw: ``(F,)`` bool faces to draw (:func:`~bop_cender.render.raster.front_faces`).
        faces: ``(F, 3)`` int64; face_instance: ``(F,)`` int64 (the rotation ``R[instance]`` of its normals);
            corner_normals: ``(F, 3, 3)`` model frame.
        R: ``(I, 3, 3)`` float32 rotations; K_inv: ``(9,)`` float32 inverse intrinsics, row-major.
        face_bits, depth_bits: > 0: int32 keys of 1/z quantised over the canvas's depth range into ``depth_bits``
            bits, face id in ``face_bits`` bits (:class:`~bop_cender.render.scanline.KeyCodec`); 0: exact keys (1/z,
            ties to the larger face id).
        fused: torch's ``addcmul`` rounds once (a fused multiply-add: :data:`ADDCMUL_FUSED`).
        depth_out, normals_out, face_out: ``(h, w)``, ``(h, w, 3)``, ``(h, w)`` written at the covered pixels only
            (the caller fills the background: 0, 0, -1).
    """
    N = cam.shape[0]
    F = faces.shape[0]
    quantised = face_bits > 0
    levels = key_levels(depth_bits, quantised)
    z_lo = np.float32(np.inf)
    z_hi = np.float32(-np.inf)
    for n in range(N):
        z_lo = min(z_lo, cam[n, 2])
        z_hi = max(z_hi, cam[n, 2])
    w_lo, scale = key_scale(z_lo, z_hi, near, levels)
    best_key = np.full(h * w, -1, dtype=np.int64)  # int32 key (quantised) or face id (exact), pixel i * w + j
    best_w = np.full(h * w, -np.inf, dtype=np.float32)  # exact 1/z plane value (not quantised)
    table = np.zeros((F, TABLE_WIDTH), dtype=np.float32)
    for f in range(F):
        if not draw[f]:  # 2. culled (raster.front_faces)
            continue
        face_row(cam, faces, face_instance, corner_normals, R, K_inv, f, fused, table[f])  # 3. shading row
        qa, qb, qc = key_plane(table[f], quantised, scale, w_lo)
        scan_face(px, py, faces[f, 0], faces[f, 1], faces[f, 2], f, qa, qb, qc, v0, u0, h, w, quantised, levels,
                  face_bits, fused, best_key, best_w)  # fmt: skip
    # 5. shade the covered pixels (resolve.shade), at their centres in image coordinates
    mask = (1 << face_bits) - 1
    for i in range(h):
        y = np.float32(v0 + i) + _HALF
        for j in range(w):
            key = best_key[i * w + j]
            if key < 0:
                continue
            f = key & mask if quantised else key
            face_out[i, j] = f
            depth, n0, n1, n2 = shade(table[f], np.float32(u0 + j) + _HALF, y, fused)
            depth_out[i, j] = depth
            normals_out[i, j, 0] = n0
            normals_out[i, j, 1] = n1
            normals_out[i, j, 2] = n2


@cached_njit(nogil=True, error_model="numpy", inline="always")
def keep_fragment(best_key, best_w, p, q, key, f, quantised):
    """The z-buffer test at pixel ``p`` (CPU): the larger int32 key wins (quantised), or the larger exact 1/z ``q``,
    ties to the larger face id (torch packs the float's bits: a negative or NaN 1/z never wins)."""
    if quantised:
        if key > best_key[p]:
            best_key[p] = key
    elif q >= 0 and (q > best_w[p] or (q == best_w[p] and f > best_key[p])):
        best_w[p] = q
        best_key[p] = f


@cached_njit(nogil=True, error_model="numpy", inline="always")
def sqrt32(x):
    """The float32 square root, correctly rounded (IEEE's, as :func:`~bop_cender.render.curvature.
    correctly_rounded_sqrt_` takes torch's): NumPy's on the CPU; CUDA's ``math.sqrt`` of a float32 on the GPU
    (:mod:`bop_cender.render.cuda_loops`)."""
    return np.sqrt(x)


#: The rasteriser's steps compiled for the CPU (:mod:`bop_cender.render.raster_arithmetic`, the source the CUDA
#: kernels compile too), inlined where they are called.
CPU_ARITHMETIC = raster_arithmetic(cached_njit(nogil=True, error_model="numpy", inline="always"), keep_fragment, sqrt32)
torch_fma = CPU_ARITHMETIC.torch_fma
key_levels = CPU_ARITHMETIC.key_levels
key_scale = CPU_ARITHMETIC.key_scale
face_row = CPU_ARITHMETIC.face_row
key_plane = CPU_ARITHMETIC.key_plane
scan_face = CPU_ARITHMETIC.scan_face
shade = CPU_ARITHMETIC.shade
pixel_curvature = CPU_ARITHMETIC.pixel_curvature


def _addcmul_is_fused() -> bool | None:
    """Whether torch's CPU ``addcmul`` rounds once (True: AVX2 / AVX-512 kernels contract it into a fused
    multiply-add), twice (False: e.g. ``ATEN_CPU_CAPABILITY=default``), or either depending on the element (None).
    Probed on 67 elements (vectorised body and scalar tail): ``(1 + 2^-12)^2 - (1 + 2^-11)`` is 2^-24 fused, 0 not."""
    a = torch.full((67,), 1.0 + 2.0**-12, dtype=torch.float32)
    c = torch.full((67,), -(1.0 + 2.0**-11), dtype=torch.float32)
    r = torch.addcmul(c, a, a)
    if bool((r == 2.0**-24).all()):
        return True
    if bool((r == 0.0).all()):
        return False
    return None


#: How torch's CPU ``addcmul`` rounds on this machine (probed once): the compiled loops repeat it. None (mixed): they
#: cannot, and the CPU keeps the torch pipeline (:data:`AVAILABLE` False).
ADDCMUL_FUSED = _addcmul_is_fused()
#: Whether the compiled loops give the torch pipeline's bits here (the ``auto`` backend's renders and candidate costs use them
#: by default on the CPU only then).
AVAILABLE = ADDCMUL_FUSED is not None


def key_bits(codec: KeyCodec) -> tuple[int, int]:
    """``(face_bits, depth_bits)`` of an int32 codec, ``(0, 0)`` for exact int64 keys (the loops' convention)."""
    return (codec.face_bits, codec.depth_bits) if codec.dtype == torch.int32 else (0, 0)


def loop_inputs(meshes: RenderMesh | PackedMeshes, R: torch.Tensor, t: torch.Tensor, K: torch.Tensor, near: float,
                verts: torch.Tensor | None = None) -> tuple | None:  # fmt: skip
    """The arrays :func:`raster_window` reads for C canvases (:func:`loop_tensors` as NumPy arrays), then the
    ``addcmul`` rounding; None where a vertex lies behind the near plane.

    Raises:
        RuntimeError: the loops cannot give torch's bits on this machine (:data:`AVAILABLE` False).
    """
    if not AVAILABLE:
        raise RuntimeError("torch's CPU addcmul rounds once for some elements and twice for others here: the "
                           "compiled renderer cannot repeat it (use the torch pipeline)")  # fmt: skip
    tensors = loop_tensors(meshes, R, t, K, near, verts)
    if tensors is None:
        return None
    return (*(_np(x) for x in tensors[:-2]), *tensors[-2:], bool(ADDCMUL_FUSED))


def loop_tensors(meshes: RenderMesh | PackedMeshes, R: torch.Tensor, t: torch.Tensor, K: torch.Tensor, near: float,
                 verts: torch.Tensor | None = None, check_near: bool = True) -> tuple | None:  # fmt: skip
    """What the per-canvas loops read for C canvases, from the torch renderer's own functions, as tensors on the
    inputs' device: camera-space vertices ``(C, N, 3)``, projections ``(C, N)`` twice, faces drawn ``(C, F)``, faces
    ``(F, 3)`` int64, face instances ``(F,)`` int64, corner normals ``(F, 3, 3)``, rotations ``(C, I, 3, 3)``, inverse
    intrinsics ``(C, 9)``, then the key codec's face bits and depth bits (ints); None where a vertex lies behind the
    near plane (with ``check_near``: one host synchronisation; without it the caller checks).

    Args:
        R, t: ``(C, I, 3, 3)``, ``(C, I, 3)``; K: ``(C, 3, 3)``, all float32 on one device.
        verts: ``(3, C, N)`` camera-space vertices if already computed.
    """
    verts = camera_vertices(meshes, R, t) if verts is None else verts  # (3, C, N)
    if check_near and verts.numel() and float(verts[2].amin()) < near:
        return None
    C, F = int(R.shape[0]), int(meshes.faces.shape[0])
    px, py = project_vertices(verts, K, near)
    face_instance = getattr(meshes, "face_instance", None)
    face_bits, depth_bits = key_bits(KeyCodec.for_faces(F, exact=face_instance is not None))
    if face_instance is None:
        face_instance = torch.zeros(F, dtype=torch.int64, device=verts.device)
    K_inv = torch.linalg.inv_ex(K.double())[0].to(torch.float32).reshape(C, 9)  # inv's values, without its check's sync
    return (
        verts.permute(1, 2, 0).contiguous(), px, py, front_faces(meshes, R, t), meshes.faces.to(torch.int64),
        face_instance, meshes.corner_normals, R, K_inv, int(face_bits), int(depth_bits),
    )  # fmt: skip


def render_compiled(
    meshes: RenderMesh | PackedMeshes,
    R: torch.Tensor,
    t: torch.Tensor,
    K: torch.Tensor,
    height: int,
    width: int,
    near: float = DEFAULT_NEAR,
    offsets: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None:
    """Depth ``(C, H, W)`` (z in mm, 0 on background), unit normals ``(C, H, W, 3)`` and face ids ``(C, H, W)``
    (packed index, -1 on background) of a mesh or packed meshes in C canvases, bit for bit as the torch
    pipeline (:func:`~bop_cender.render.raster.rasterize` and :func:`~bop_cender.render.resolve.resolve`) gives them:
    int32 quantised keys for one :class:`RenderMesh` of few faces, exact keys for packed meshes.

    Args:
        meshes: a CPU :class:`~bop_cender.render.mesh.RenderMesh` or :class:`~bop_cender.render.mesh.PackedMeshes`.
        R: ``(C, I, 3, 3)`` float32 model-to-camera rotations of the I instances, ``t``: ``(C, I, 3)`` (mm), CPU.
        K: ``(C, 3, 3)`` float32 intrinsics, CPU.
        height, width: canvas size.
        near: near plane (mm).
        offsets: ``(C, 2)`` int64 each canvas's window origin (row, column) in its image; None: the full frame.

    Returns:
        the maps; None where a vertex lies behind the near plane in some canvas (the torch renderer cuts the faces
        there: use it).

    Raises:
        RuntimeError: the loops cannot give torch's bits on this machine (:data:`AVAILABLE` False).
    """
    inputs = loop_inputs(meshes, R, t, K, near)
    if inputs is None:
        return None
    cam, px, py, draw, faces, face_instance, corner_normals, rotations, K_inv, face_bits, depth_bits, fused = inputs
    C = int(R.shape[0])
    origins = np.zeros((C, 2), dtype=np.int64) if offsets is None else _np(offsets.to(torch.int64))
    depth = np.zeros((C, height, width), dtype=np.float32)
    normals = np.zeros((C, height, width, 3), dtype=np.float32)
    face_map = np.full((C, height, width), -1, dtype=np.int64)
    _render_canvases(cam, px, py, draw, faces, face_instance, corner_normals, rotations, K_inv, origins, int(height),
                     int(width), np.float32(near), face_bits, depth_bits, fused, depth, normals, face_map)  # fmt: skip
    return torch.from_numpy(depth), torch.from_numpy(normals), torch.from_numpy(face_map)
