"""Which code renders: the torch pipeline, or numba's compiled loops on the CPU and kernels on CUDA, chosen once.

Why one object. The renderer exists three times: the torch pipeline (:mod:`bop_cender.render.raster`,
:mod:`bop_cender.render.resolve`: any device, any geometry), numba's compiled CPU loop
(:mod:`bop_cender.render.compiled_raster`: the same bits without the pipeline's ~2,000 operators a call) and a CUDA
kernel (:mod:`bop_cender.render.cuda_render`: one launch a call, the same maps to float32 rounding). Which one runs,
and what happens where the fast one cannot (a vertex behind the near plane, which only the torch pipeline clips;
numba's CUDA target missing; a kernel that failed to compile; CPU loops that cannot repeat torch's rounding on this
machine), is decided here and nowhere else. Stage 3's costs extend the same objects
(:mod:`bop_cender.pose.backend`).

The names (:data:`BACKEND_NAMES`, the setting ``poses.backend``):

- ``torch``: the torch pipeline everywhere (:class:`TorchRender`).
- ``numba``: numba's loops on the CPU, its kernels on CUDA (:class:`NumbaRender` with ``insist``): where numba cannot
  run at all (numba-cuda missing, a kernel that failed, CPU loops that cannot repeat torch's rounding) an error says
  why.
- ``auto`` (the default): as ``numba``, but where numba cannot run, the torch pipeline, with one warning saying why.
  This is what every entry point did before the backends had a name, on the CPU and on CUDA: no number changes.

In every backend, geometry behind the near plane is rendered by the torch pipeline (warned once).
"""

from __future__ import annotations

import warnings
from abc import ABC, abstractmethod
from collections.abc import Callable
from functools import partial
from typing import TypeVar

import torch

from bop_cender.render.cuda_loops import KernelGuard
from bop_cender.render.mesh import PackedMeshes, RenderMesh
from bop_cender.render.raster import rasterize
from bop_cender.render.resolve import WindowMaps, resolve
from bop_cender.render.settings import DEFAULT_RENDER_SETTINGS
from bop_cender.render.window import Windows

#: The backends by name: what ``poses.backend`` (and :func:`render_backend_named`) accept.
BACKEND_NAMES = ("auto", "torch", "numba")

#: Window pixels rendered per chunk by the torch pipeline (all canvases of a chunk together); bounds the z-buffer and
#: the fragment arrays. 2^21 pixels is about 16 MB of int64 keys.
DEFAULT_CHUNK_PIXELS = DEFAULT_RENDER_SETTINGS.scene_chunk_pixels

Maps = tuple[torch.Tensor, torch.Tensor, torch.Tensor]
T_out = TypeVar("T_out")


class RenderBackend(ABC):
    """How the renderer's canvases are drawn (the module docstring): one object per backend, chosen once
    (:func:`render_backend_named`) and passed to :func:`~bop_cender.render.rasterizer.render_scene` and the other
    entry points. Every method takes float32 tensors on one device and returns tensors there.

    Attributes:
        name: the backend's name (one of :data:`BACKEND_NAMES`).
    """

    name: str

    def __init__(self) -> None:
        self._warned: set[str] = set()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name!r}>"

    @abstractmethod
    def scene_maps(self, packed: PackedMeshes, R: torch.Tensor, t: torch.Tensor, K: torch.Tensor, height: int,
                   width: int, near: float) -> Maps:  # fmt: skip
        """Depth ``(V, H, W)`` (z in mm, 0 on background), unit normals ``(V, H, W, 3)`` and packed face ids ``(V, H,
        W)`` (-1 on background) of packed meshes in V full frames (``R (V, I, 3, 3)``, ``t (V, I, 3)``, ``K (V, 3,
        3)``), exact keys (ties to the larger face id)."""

    @abstractmethod
    def window_maps(self, mesh: RenderMesh, T: torch.Tensor, K: torch.Tensor, offsets: torch.Tensor,
                    size: tuple[int, int], near: float, depth: bool = True, normals: bool = True,
                    faces: bool = True) -> WindowMaps:  # fmt: skip
        """One mesh in C canvases ``T (C, 4, 4)``, ``K (C, 3, 3)``, windows of ``size (h, w)`` at ``offsets (C, 2)``
        (row, column), int32 keys of quantised depth; the maps not asked for are None."""

    def warn_once(self, message: str) -> None:
        """Warn ``message`` the first time it comes up for this backend object (a run has one)."""
        if message not in self._warned:
            self._warned.add(message)
            warnings.warn(message, RuntimeWarning, stacklevel=3)


class TorchRender(RenderBackend):
    """The torch pipeline (:func:`~bop_cender.render.raster.rasterize`, :func:`~bop_cender.render.resolve.resolve`)
    in chunks of :data:`DEFAULT_CHUNK_PIXELS`: any device, any geometry (faces are cut at the near plane)."""

    name = "torch"

    def scene_maps(self, packed: PackedMeshes, R: torch.Tensor, t: torch.Tensor, K: torch.Tensor, height: int,
                   width: int, near: float) -> Maps:  # fmt: skip
        V, device = int(R.shape[0]), R.device
        chunks = _chunks(V, max(1, DEFAULT_CHUNK_PIXELS // (height * width)))
        # one chunk: its maps are the maps (no copy)
        merged = None if len(chunks) == 1 and V > 0 else _empty_maps(V, height, width, device)
        for views in chunks:
            n = views.stop - views.start
            windows = Windows.uniform(torch.zeros((n, 2), dtype=torch.int64, device=device), height, width)
            maps = resolve(rasterize(packed, R[views], t[views], K[views], windows, near))
            if merged is None:
                merged = maps
            else:
                _copy_maps(merged, views, maps)
        return merged.depth, merged.normals, merged.face

    def window_maps(self, mesh: RenderMesh, T: torch.Tensor, K: torch.Tensor, offsets: torch.Tensor,
                    size: tuple[int, int], near: float, depth: bool = True, normals: bool = True,
                    faces: bool = True) -> WindowMaps:  # fmt: skip
        C = int(T.shape[0])
        out = _empty_maps(C, size[0], size[1], T.device, depth, normals, faces)
        for rows in _chunks(C, max(1, DEFAULT_CHUNK_PIXELS // (size[0] * size[1]))):
            windows = Windows.uniform(offsets[rows], size[0], size[1])
            raster = rasterize(mesh, T[rows, None, :3, :3], T[rows, None, :3, 3], K[rows], windows, near,
                               normals=normals)  # fmt: skip
            _copy_maps(out, rows, resolve(raster, depth=depth, normals=normals, faces=faces))
        return out


class NumbaRender(RenderBackend):
    """numba's compiled loop on the CPU (:func:`~bop_cender.render.compiled_raster.render_compiled`: the torch
    pipeline's bits) and its kernel on CUDA (:mod:`bop_cender.render.cuda_render`, packed meshes; one mesh's windows
    take the torch pipeline there); the torch pipeline (:attr:`torch`) for geometry behind the near plane, warned once,
    and on other devices.

    Args:
        insist: where numba cannot run at all (the CPU loops cannot repeat torch's rounding here, numba's CUDA target
            is missing, the kernel failed), raise instead of warning once and rendering with the torch pipeline
            (``numba`` against ``auto``).
    """

    def __init__(self, insist: bool = False) -> None:
        super().__init__()
        self.insist = insist
        self.name = "numba" if insist else "auto"
        #: The torch pipeline, for what the loops and kernels leave to it.
        self.torch = TorchRender()

    def scene_maps(self, packed: PackedMeshes, R: torch.Tensor, t: torch.Tensor, K: torch.Tensor, height: int,
                   width: int, near: float) -> Maps:  # fmt: skip
        device = R.device
        if R.shape[0] > 0 and device.type == "cuda":
            from bop_cender.render import cuda_render  # numba: imported where it is used

            compute = partial(cuda_render.cuda_render, packed, R, t, K, height, width, near)
            maps = self.run_kernel(cuda_render.GUARD, compute, "render_scene's CUDA kernel")
            if maps is not None:
                return maps
        elif R.shape[0] > 0 and self.cpu_loops(device):
            from bop_cender.render.compiled_raster import render_compiled  # numba: imported where it is used

            maps = render_compiled(packed, R, t, K, height, width, near)
            if maps is not None:
                return maps
            self.near_plane("render_scene's compiled loop")
        return self.torch.scene_maps(packed, R, t, K, height, width, near)

    def window_maps(self, mesh: RenderMesh, T: torch.Tensor, K: torch.Tensor, offsets: torch.Tensor,
                    size: tuple[int, int], near: float, depth: bool = True, normals: bool = True,
                    faces: bool = True) -> WindowMaps:  # fmt: skip
        if T.shape[0] > 0 and self.cpu_loops(T.device):
            from bop_cender.render.compiled_raster import render_compiled  # numba: imported where it is used

            maps = render_compiled(mesh, T[:, None, :3, :3], T[:, None, :3, 3], K, *size, near, offsets)
            if maps is not None:
                d, n, f = maps
                return WindowMaps(f >= 0, f if faces else None, d if depth else None, n if normals else None)
            self.near_plane("the compiled loop")
        return self.torch.window_maps(mesh, T, K, offsets, size, near, depth, normals, faces)

    def cpu_loops(self, device: torch.device) -> bool:
        """Whether the compiled CPU loops serve ``device``: on the CPU, where they repeat torch's ``addcmul`` rounding
        (:data:`~bop_cender.render.compiled_raster.AVAILABLE`); where they cannot, the torch pipeline, warned once
        (with ``insist``: an error).

        Raises:
            RuntimeError: with ``insist``, on the CPU, where the loops cannot repeat torch's rounding.
        """
        if device.type != "cpu":
            return False
        from bop_cender.render import compiled_raster  # numba: imported where it is used

        if not compiled_raster.AVAILABLE:
            why = "torch's CPU addcmul rounds once for some elements and twice for others here"
            if self.insist:
                raise RuntimeError(f"the numba backend's CPU loops cannot repeat the torch renderer: {why} "
                                   "(backend auto or torch: the torch pipeline)")  # fmt: skip
            self.warn_once(f"the CPU renders run the torch pipeline: {why}")
        return compiled_raster.AVAILABLE

    def run_kernel(self, guard: KernelGuard, compute: Callable[[], T_out | None], what: str | None) -> T_out | None:
        """``compute()`` (a call of a CUDA kernel) through its ``guard``: its result, or None where the torch code is to
        serve: the kernel cannot run here (the guard warns once; with ``insist``, raises), or it declined the call
        (``compute`` returned None: geometry behind the near plane, warned once here as ``what``'s; None: not
        warned, for a call with nothing to draw).

        Raises:
            RuntimeError: with ``insist``, where the kernel cannot run (:meth:`KernelGuard.run`).
        """
        declined: list[bool] = []

        def call() -> T_out | None:
            out = compute()
            declined.append(out is None)
            return out

        out = guard.run(call, self.insist)
        if out is None and declined and declined[0] and what is not None:
            self.near_plane(what)
        return out

    def near_plane(self, what: str) -> None:
        """Say once that ``what`` left a call to the torch pipeline: a vertex behind the near plane, which only the
        torch pipeline clips."""
        self.warn_once(f"{what} leaves geometry behind the near plane to the torch pipeline, which clips it")


def render_backend_named(name: str) -> RenderBackend:
    """The render backend called ``name`` (:data:`BACKEND_NAMES`), one object per name in a process (its warnings
    are said once).

    Raises:
        ValueError: an unknown name.
    """
    if name not in _RENDER_BACKENDS:
        raise ValueError(f"unknown backend {name!r}; expected one of {', '.join(BACKEND_NAMES)}")
    return _RENDER_BACKENDS[name]


_RENDER_BACKENDS: dict[str, RenderBackend] = {"auto": NumbaRender(), "torch": TorchRender(), "numba": NumbaRender(True)}


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
