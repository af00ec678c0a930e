"""Public entry points of the one batched renderer: scenes (several objects, full frame) and pose
candidates (one mesh, windows). Thin over :mod:`bop_cender.render.raster` (z-buffer) and
:mod:`bop_cender.render.resolve` (shading).

Everything is float32 on the device of the inputs (a torch ``T_cam_model`` decides; with NumPy poses the
mesh's device does); batches are cut into chunks so that memory stays bounded.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
import torch

from bop_cender.geometry.check import check_shape
from bop_cender.render.mesh import PackedMeshes, RenderMesh, pack_meshes
from bop_cender.render.raster import DEFAULT_NEAR, rasterize
from bop_cender.render.resolve import WindowMaps, resolve
from bop_cender.render.settings import DEFAULT_RENDER_SETTINGS
from bop_cender.render.window import Windows, window_offsets, window_size

#: Window pixels rendered per chunk (all canvases of a chunk together); bounds the z-buffer and the
#: fragment arrays. 2^21 pixels is about 16 MB of int64 keys.
DEFAULT_CHUNK_PIXELS = DEFAULT_RENDER_SETTINGS.scene_chunk_pixels

TensorLike = torch.Tensor | np.ndarray


@dataclass(frozen=True)
class SceneRender:
    """Full-frame render of several objects in V views.

    Attributes:
        depth: ``(V, H, W)`` float32 z in mm (not distance), 0 on background.
        normals: ``(V, H, W, 3)`` float32 camera-space unit normals, 0 on background.
        packed_face: ``(V, H, W)`` int64 face index among all the meshes' faces (packed), -1 on background.
        face_instance, face_local: ``(F,)`` int64 mesh and face within it of each packed face.

    ``instance`` and ``face`` (below) are worked out from ``packed_face`` when first read: a render whose caller
    wants only depth and normals (stage 3's costs, thousands of renders a scene) does not pay for them.
    """

    depth: torch.Tensor
    normals: torch.Tensor
    packed_face: torch.Tensor
    face_instance: torch.Tensor
    face_local: torch.Tensor

    @cached_property
    def instance(self) -> torch.Tensor:
        """``(V, H, W)`` int64 index into the rendered meshes, -1 on background."""
        return self._per_face(self.face_instance)

    @cached_property
    def face(self) -> torch.Tensor:
        """``(V, H, W)`` int64 face index within that mesh, -1 on background."""
        return self._per_face(self.face_local)

    @property
    def mask(self) -> torch.Tensor:
        """``(V, H, W)`` bool, any object."""
        return self.packed_face >= 0

    def _per_face(self, table: torch.Tensor) -> torch.Tensor:
        return torch.where(self.packed_face >= 0, table[self.packed_face.clamp_min(0)], -1)


@dataclass(frozen=True)
class ObjectsRender:
    """Each object rendered alone (full silhouettes, for BOP ``mask/`` and visib_fract).

    Attributes:
        depth: ``(V, M, H, W)`` float32 z in mm of object m alone in view v, 0 where it is absent.
    """

    depth: torch.Tensor

    @property
    def mask(self) -> torch.Tensor:
        """``(V, M, H, W)`` bool full silhouettes."""
        return self.depth > 0


@dataclass(frozen=True)
class CandidateRender:
    """B pose candidates of one mesh in V views, each rendered in an ``S x S`` window.

    Attributes:
        normals: ``(B, V, S, S, 3)`` float32 camera-space unit normals, 0 on background (None when not asked for).
        mask: ``(B, V, S, S)`` bool.
        depth: ``(B, V, S, S)`` float32 z in mm, 0 on background (None when not asked for).
        offsets: ``(B, V, 2)`` int64 image pixel of each window's first pixel: (row v0, column u0).
            Window pixel (i, j) is image pixel (v0 + i, u0 + j); pixels beyond the image border are
            rendered too (as if the image went on).
    """

    normals: torch.Tensor | None
    mask: torch.Tensor
    depth: torch.Tensor | None
    offsets: torch.Tensor

    @property
    def size(self) -> int:
        return int(self.mask.shape[-1])


def render_scene(
    meshes: Sequence[RenderMesh] | PackedMeshes,
    T_cam_model: TensorLike,
    K: TensorLike,
    height: int,
    width: int,
    near: float = DEFAULT_NEAR,
    compiled: bool | None = None,
) -> SceneRender:
    """Render M objects (each its own mesh) together in V views, with occlusion between them.

    Args:
        meshes: M meshes (or already packed), in the order of ``T_cam_model``'s second axis.
        T_cam_model: ``(V, M, 4, 4)`` model-to-camera transforms (mm).
        K: ``(V, 3, 3)`` intrinsics.
        height, width: image size.
        near: near plane (mm); nothing closer is drawn.
        compiled: on the CPU, render with the compiled loop (:mod:`bop_cender.render.compiled_raster`: the same
            bits, without the torch pipeline's fixed cost of about 2,000 operators a call), on CUDA with its kernel
            (:mod:`bop_cender.render.cuda_render`: one launch, the same maps to float32 rounding); None (default): on
            the CPU where the loops can repeat torch's rounding (``compiled_raster.AVAILABLE``), on CUDA where numba's
            CUDA target works (else warned once), unless a vertex is behind the near plane (the torch pipeline cuts
            faces there); False: the torch pipeline.

    Returns:
        Depth, normals, instance and face maps ``(V, H, W, ...)``.
    """
    sizes = check_shape(T_cam_model, "V M 4 4", "T_cam_model")
    check_shape(K, "V 3 3", "K", sizes)
    packed = meshes if isinstance(meshes, PackedMeshes) else pack_meshes(list(meshes))
    device = _device(T_cam_model, packed.device)
    packed = _packed_to(packed, device)
    T = _as_f32(T_cam_model, device)
    Ks = _as_f32(K, device)
    V, M = int(T.shape[0]), int(T.shape[1])
    if packed.num_meshes != M:
        raise ValueError(f"T_cam_model has {M} objects but {packed.num_meshes} meshes were given")
    R, t = T[..., :3, :3], T[..., :3, 3]
    from bop_cender.render import compiled_raster  # numba: imported where it is used

    if device.type == "cuda" and compiled is not False:
        if V > 0:
            from bop_cender.render import cuda_render  # numba: imported where it is used

            maps = cuda_render.render_or_none(packed, R, t, Ks, height, width, near, compiled)
            if maps is not None:
                return SceneRender(*maps, packed.face_instance, packed.face_local)
            compiled_raster.behind_near_plane(compiled)  # compiled=True: the kernel declined (the near plane)
        compiled = False  # the torch pipeline (a vertex behind the near plane, no kernel, or nothing to draw)

    if compiled_raster.use_compiled(compiled, device) and V > 0:
        maps = compiled_raster.render_compiled(packed, R, t, Ks, height, width, near)
        if maps is not None:
            return SceneRender(*maps, packed.face_instance, packed.face_local)
        compiled_raster.behind_near_plane(compiled)
    chunks = _chunks(V, max(1, DEFAULT_CHUNK_PIXELS // (height * width)))
    # one chunk: its maps are the maps (no copy)
    merged = None if len(chunks) == 1 and V > 0 else _empty_maps(V, height, width, device)
    for views in chunks:
        n = views.stop - views.start
        windows = Windows.uniform(torch.zeros((n, 2), dtype=torch.int64, device=device), height, width)
        maps = resolve(rasterize(packed, R[views], t[views], Ks[views], windows, near))
        if merged is None:
            merged = maps
        else:
            _copy_maps(merged, views, maps)
    return SceneRender(merged.depth, merged.normals, merged.face, packed.face_instance, packed.face_local)


def render_objects_separately(
    meshes: Sequence[RenderMesh],
    T_cam_model: TensorLike,
    K: TensorLike,
    height: int,
    width: int,
    near: float = DEFAULT_NEAR,
) -> ObjectsRender:
    """Render each of M objects alone in V views (no occlusion between them): depth ``(V, M, H, W)``.

    Args and conventions as :func:`render_scene`.
    """
    sizes = check_shape(T_cam_model, "V M 4 4", "T_cam_model")
    check_shape(K, "V 3 3", "K", sizes)
    device = _device(T_cam_model, meshes[0].device if meshes else torch.device("cpu"))
    T = _as_f32(T_cam_model, device)
    Ks = _as_f32(K, device)
    V, M = int(T.shape[0]), int(T.shape[1])
    if len(meshes) != M:
        raise ValueError(f"T_cam_model has {M} objects but {len(meshes)} meshes were given")
    depth = torch.zeros((V, M, height, width), dtype=torch.float32, device=device)
    for m, mesh in enumerate(meshes):
        maps = _render_windows(mesh.to(device), T[:, m], Ks, None, (height, width), near, normals=False, faces=False)
        depth[:, m] = maps.depth
    return ObjectsRender(depth=depth)


def render_candidates(
    mesh: RenderMesh,
    T_cam_model: TensorLike,
    K: TensorLike,
    height: int,
    width: int,
    window: int | None = None,
    near: float = DEFAULT_NEAR,
    depth: bool = True,
    normals: bool = True,
) -> CandidateRender:
    """Render B pose candidates of one mesh in V views, each in a square window around its origin.

    Args:
        mesh: the object.
        T_cam_model: ``(B, V, 4, 4)`` model-to-camera transforms (mm).
        K: ``(V, 3, 3)`` intrinsics.
        height, width: image size (bounds the automatic window size).
        window: S; None picks the smallest multiple of 8 that holds the object's bounding sphere in
            every candidate and view (:func:`bop_cender.render.window.window_size`).
        near: near plane (mm).
        depth: also return depth (the cost function needs only normals).
        normals: also return normals (VSD needs only depth: skipping them saves 10-20 %).

    Returns:
        Normals (None when not asked for), mask, depth in the windows ``(B, V, S, S, ...)`` and the windows' offsets ``(B, V, 2)``.
    """
    sizes = check_shape(T_cam_model, "B V 4 4", "T_cam_model")
    check_shape(K, "V 3 3", "K", sizes)
    device = _device(T_cam_model, mesh.device)
    mesh = mesh.to(device)
    T = _as_f32(T_cam_model, device)
    Ks = _as_f32(K, device)
    B, V = int(T.shape[0]), int(T.shape[1])
    S = int(window) if window is not None else window_size(mesh.radius, T, Ks, height, width, near)
    offsets = window_offsets(T, Ks, S)
    maps = _render_windows(
        mesh,
        T.reshape(B * V, 4, 4),
        Ks.repeat(B, 1, 1),
        offsets.reshape(B * V, 2),
        (S, S),
        near,
        depth,
        normals=normals,
        faces=False,
    )
    return CandidateRender(
        normals=None if maps.normals is None else maps.normals.view(B, V, S, S, 3),
        mask=maps.mask.view(B, V, S, S),
        depth=None if maps.depth is None else maps.depth.view(B, V, S, S),
        offsets=offsets,
    )


def _render_windows(
    mesh: RenderMesh,
    T: torch.Tensor,
    K: torch.Tensor,
    offsets: torch.Tensor | None,
    size: tuple[int, int],
    near: float,
    depth: bool = True,
    normals: bool = True,
    faces: bool = True,
) -> WindowMaps:
    """One mesh in C canvases ``T (C, 4, 4)``, ``K (C, 3, 3)``, windows at ``offsets (C, 2)`` (None: 0).

    On the CPU through the compiled loop (:mod:`bop_cender.render.compiled_raster`: the same bits) where it can."""
    C = int(T.shape[0])
    if offsets is None:
        offsets = torch.zeros((C, 2), dtype=torch.int64, device=T.device)
    from bop_cender.render import compiled_raster  # numba: imported where it is used

    if compiled_raster.use_compiled(None, T.device) and C > 0:
        maps = compiled_raster.render_compiled(mesh, T[:, None, :3, :3], T[:, None, :3, 3], K, *size, near, offsets)
        if maps is not None:
            d, n, f = maps
            return WindowMaps(f >= 0, f if faces else None, d if depth else None, n if normals else None)
    out = _empty_maps(C, size[0], size[1], T.device, depth, normals, faces)
    for rows in _chunks(C, max(1, DEFAULT_CHUNK_PIXELS // (size[0] * size[1]))):
        windows = Windows.uniform(offsets[rows], size[0], size[1])
        raster = rasterize(mesh, T[rows, None, :3, :3], T[rows, None, :3, 3], K[rows], windows, near, normals=normals)
        _copy_maps(out, rows, resolve(raster, depth=depth, normals=normals, faces=faces))
    return out


def _chunks(n: int, size: int) -> list[slice]:
    return [slice(i, min(n, i + size)) for i in range(0, n, size)] or [slice(0, 0)]


def _empty_maps(
    C: int, h: int, w: int, device: torch.device, depth: bool = True, normals: bool = True, faces: bool = True
) -> WindowMaps:
    return WindowMaps(
        mask=torch.zeros((C, h, w), dtype=torch.bool, device=device),
        face=torch.full((C, h, w), -1, dtype=torch.int64, device=device) if faces else None,
        depth=torch.zeros((C, h, w), dtype=torch.float32, device=device) if depth else None,
        normals=torch.zeros((C, h, w, 3), dtype=torch.float32, device=device) if normals else None,
    )


def _copy_maps(out: WindowMaps, rows: slice, part: WindowMaps) -> None:
    for name in ("mask", "face", "depth", "normals"):
        dst = getattr(out, name)
        if dst is not None:
            dst[rows] = getattr(part, name)


def _device(T: TensorLike, default: torch.device) -> torch.device:
    return T.device if isinstance(T, torch.Tensor) else default


def _as_f32(x: TensorLike, device: torch.device) -> torch.Tensor:
    return torch.as_tensor(x, device=device).to(torch.float32)


def _packed_to(p: PackedMeshes, device: torch.device) -> PackedMeshes:
    if p.device == device:
        return p
    return replace(p, **{f: getattr(p, f).to(device) for f in p.__dataclass_fields__ if f != "vertex_counts"})
