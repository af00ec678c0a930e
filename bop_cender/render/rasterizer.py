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
from bop_cender.render.backend import RenderBackend, render_backend_named
from bop_cender.render.mesh import PackedMeshes, RenderMesh, pack_meshes
from bop_cender.render.raster import DEFAULT_NEAR
from bop_cender.render.resolve import WindowMaps
from bop_cender.render.window import window_offsets, window_size

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
    backend: RenderBackend | None = None,
) -> SceneRender:
    """Render M objects (each its own mesh) together in V views, with occlusion between them.

    Args:
        meshes: M meshes (or already packed), in the order of ``T_cam_model``'s second axis.
        T_cam_model: ``(V, M, 4, 4)`` model-to-camera transforms (mm).
        K: ``(V, 3, 3)`` intrinsics.
        height, width: image size.
        near: near plane (mm); nothing closer is drawn.
        backend: which code draws (:mod:`bop_cender.render.backend`); None: ``auto``, the compiled loop on the CPU
            (the torch pipeline's bits without its fixed cost of about 2,000 operators a call), the CUDA kernel on
            CUDA (the same maps to float32 rounding), each where it can run, else the torch pipeline.

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
    M = int(T.shape[1])
    if packed.num_meshes != M:
        raise ValueError(f"T_cam_model has {M} objects but {packed.num_meshes} meshes were given")
    R, t = T[..., :3, :3], T[..., :3, 3]
    backend = render_backend_named("auto") if backend is None else backend
    depth, normals, face = backend.scene_maps(packed, R, t, Ks, height, width, near)
    return SceneRender(depth, normals, face, packed.face_instance, packed.face_local)


def render_objects_separately(
    meshes: Sequence[RenderMesh],
    T_cam_model: TensorLike,
    K: TensorLike,
    height: int,
    width: int,
    near: float = DEFAULT_NEAR,
    backend: RenderBackend | None = None,
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
        maps = _render_windows(mesh.to(device), T[:, m], Ks, None, (height, width), near, backend, normals=False,
                               faces=False)  # fmt: skip
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
    backend: RenderBackend | None = None,
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
        backend: as :func:`render_scene`.

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
        backend,
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
    backend: RenderBackend | None,
    depth: bool = True,
    normals: bool = True,
    faces: bool = True,
) -> WindowMaps:
    """One mesh in C canvases ``T (C, 4, 4)``, ``K (C, 3, 3)``, windows at ``offsets (C, 2)`` (None: 0), drawn by
    ``backend`` (None: ``auto``, the compiled loop on the CPU)."""
    if offsets is None:
        offsets = torch.zeros((int(T.shape[0]), 2), dtype=torch.int64, device=T.device)
    backend = render_backend_named("auto") if backend is None else backend
    return backend.window_maps(mesh, T, K, offsets, size, near, depth, normals, faces)


def _device(T: TensorLike, default: torch.device) -> torch.device:
    return T.device if isinstance(T, torch.Tensor) else default


def _as_f32(x: TensorLike, device: torch.device) -> torch.Tensor:
    return torch.as_tensor(x, device=device).to(torch.float32)


def _packed_to(p: PackedMeshes, device: torch.device) -> PackedMeshes:
    if p.device == device:
        return p
    return replace(p, **{f: getattr(p, f).to(device) for f in p.__dataclass_fields__ if f != "vertex_counts"})
