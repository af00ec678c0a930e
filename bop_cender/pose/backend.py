"""Stage 3's computations by backend: torch operators, or numba's compiled loops on the CPU and kernels on CUDA.

Why one object. Five computations of stage 3 exist as torch code, as numba CPU loops and as numba CUDA kernels: the
render (:func:`~bop_cender.render.rasterizer.render_scene`), the candidates' render cost (:meth:`Backend.candidate_costs`),
the edge proxy (:meth:`Backend.edge_costs`), the scene cost (:meth:`Backend.scene_cost`) and the scene polish's
windowed scene cost (:meth:`Backend.window_costs`). A :class:`Backend` implements all five; a run chooses one by name,
once (:func:`backend_named`, the setting ``poses.backend``), and every step takes it. Which code runs on which device,
and what happens where the fast code cannot, is written here and in :mod:`bop_cender.render.backend` only:

- ``torch`` (:class:`TorchBackend`): torch operators everywhere (the edge proxy compacted on the CPU, dense on CUDA).
- ``auto`` (the default, :class:`NumbaBackend`): numba's CPU loops on the CPU, its CUDA kernels on CUDA, each where it
  can run; where it cannot (numba-cuda missing, a kernel that failed to compile or launch, CPU loops that cannot
  repeat torch's rounding), the torch code, with one warning saying why. What each function did by default before the
  backends had a name, on the CPU and on CUDA: every number the same.
- ``numba`` (:class:`NumbaBackend` with ``insist``): the same, but where numba cannot run an error says why.

In every backend, a call whose geometry crosses the near plane (which only the torch renderer clips), or whose mesh
is too large for the cost kernel's int32 keys (more than 2^15 faces), takes the torch code, warned once.
"""

from __future__ import annotations

from abc import abstractmethod
from functools import partial

import numpy as np
import torch

from bop_cender.geometry.check import check_shape
from bop_cender.pose.cost import atlas_view_costs
from bop_cender.pose.coverage import torch_scene_cost
from bop_cender.pose.edge_cost import EDGE_COINCIDENCE_MM, SAMPLES_PER_SEGMENT, torch_edge_view_costs
from bop_cender.pose.edge_model import EdgeModel
from bop_cender.pose.scene_polish import SceneWindow, torch_window_costs, window_poses
from bop_cender.render.backend import BACKEND_NAMES, NumbaRender, RenderBackend, TorchRender
from bop_cender.render.candidate_curvature import prepare_candidates
from bop_cender.render.mesh import RenderMesh
from bop_cender.render.raster import DEFAULT_NEAR
from bop_cender.render.rasterizer import render_scene
from bop_cender.render.settings import DEFAULT_RENDER_SETTINGS, RenderSettings

ArrayLike = np.ndarray | torch.Tensor


class Backend(RenderBackend):
    """Stage 3's five computations (the module docstring), with the renderer's (:class:`RenderBackend`): pass the
    object to :func:`~bop_cender.render.rasterizer.render_scene` as its ``backend``. The public methods check shapes and
    move inputs to the poses' device, then call the backend's own steps."""

    def candidate_costs(
        self,
        mesh: RenderMesh,
        T_cam_model: ArrayLike,
        K: ArrayLike,
        height: int,
        width: int,
        dist_maps: ArrayLike,
        view_weights: ArrayLike,
        near: float = DEFAULT_NEAR,
        chunk_pixels: int | None = None,
        workers: int = 1,
        occluder_depth: ArrayLike | None = None,
        settings: RenderSettings | None = None,
    ) -> torch.Tensor:
        """The paper's render cost (:mod:`bop_cender.pose.cost`) of B candidates: ``T_cam_model (B, V, 4, 4)`` ->
        ``(B,)``, ``sum_v w_v cost_v``.

        Args:
            mesh: the object.
            T_cam_model: ``(B, V, 4, 4)`` candidate poses in each view's camera frame (mm).
            K: ``(V, 3, 3)`` intrinsics; height, width: image size.
            dist_maps: ``(V, H, W)`` float32 distance maps (:func:`~bop_cender.pose.cost.distance_maps`).
            view_weights: ``(V,)`` per-view weights.
            near: near plane (mm).
            chunk_pixels: window pixels per chunk of the torch atlases (default: small on CPU for its caches, large
                on CUDA).
            workers: threads that render the torch atlases' chunks side by side (CPU;
                :func:`~bop_cender.pose.cost.atlas_view_costs`).
            occluder_depth: ``(V, H, W)`` depth (mm) of objects already placed, 0 where none: candidate pixels behind
                it draw no curvature (the paper's sequential occlusion). None: no occluders.
            settings: near plane and chunk sizes; when given, they replace ``near`` and the default ``chunk_pixels``.

        Returns:
            ``(B,)`` float32 costs on the device of ``T_cam_model`` (a torch tensor) or of the mesh.
        """
        sizes = check_shape(T_cam_model, "B V 4 4", "T_cam_model")
        check_shape(K, "V 3 3", "K", sizes)
        check_shape(dist_maps, f"V {int(height)} {int(width)}", "dist_maps", sizes)
        check_shape(view_weights, "V", "view_weights", sizes)
        if occluder_depth is not None:
            check_shape(occluder_depth, f"V {int(height)} {int(width)}", "occluder_depth", sizes)
        device = T_cam_model.device if isinstance(T_cam_model, torch.Tensor) else mesh.device
        mesh = mesh.to(device)
        T = torch.as_tensor(T_cam_model, device=device).to(torch.float32)
        Ks = torch.as_tensor(K, device=device).to(torch.float32)
        dist = torch.as_tensor(dist_maps, device=device).to(torch.float32)
        weights = torch.as_tensor(view_weights, device=device).to(torch.float32)
        if settings is not None:
            near = settings.near
        if chunk_pixels is None:
            chunk_pixels = (settings or DEFAULT_RENDER_SETTINGS).candidate_chunk_pixels(device)
        B, V = int(T.shape[0]), int(T.shape[1])
        occ = None if occluder_depth is None else torch.as_tensor(occluder_depth, device=device).to(torch.float32)
        per_view = self.candidate_view_costs(mesh, T, Ks, height, width, near, dist, occ, chunk_pixels, workers)
        return (per_view.view(B, V) * weights).sum(1)

    @abstractmethod
    def candidate_view_costs(self, mesh: RenderMesh, T: torch.Tensor, K: torch.Tensor, height: int, width: int,
                             near: float, dist: torch.Tensor, occ: torch.Tensor | None, chunk_pixels: int,
                             workers: int) -> torch.Tensor:  # fmt: skip
        """Unweighted costs ``(B * V,)`` float32 (canvas ``c`` = candidate ``c // V`` in view ``c % V``) of
        :meth:`candidate_costs`' inputs, checked and on one device."""

    def edge_costs(
        self,
        model: EdgeModel,
        T_cam_model: torch.Tensor,
        K: torch.Tensor,
        dist_maps: torch.Tensor,
        view_weights: torch.Tensor,
        occluder_depth: torch.Tensor | None = None,
        near: float = 1.0,
    ) -> torch.Tensor:
        """The edge proxy of the render cost (:mod:`bop_cender.pose.edge_cost`) of B candidates over V views.

        Args:
            model: the object's edges (:func:`~bop_cender.pose.edge_model.edge_model`), on the device of
                ``T_cam_model``.
            T_cam_model: ``(B, V, 4, 4)`` candidate poses in each view's camera frame (mm).
            K: ``(V, 3, 3)`` intrinsics of the distance maps' resolution (a pinhole K: last row ``[0, 0, 1]``, so that
                the third homogeneous coordinate is the camera depth that ``near`` is compared with).
            dist_maps: ``(V, H, W)`` float32 distance maps of the target curvature (pixels).
            view_weights: ``(V,)``.
            occluder_depth: ``(V, H, W)`` depth (mm) of the objects already placed, 0 where none, widened by
                :func:`~bop_cender.pose.edge_cost.edge_occluder`; None: none.
            near: points closer to the camera plane than this (mm) are not drawn.

        Returns:
            ``(B,)`` float32 ``sum_v w_v cost_v`` on the device of ``T_cam_model``.
        """
        sizes = check_shape(T_cam_model, "B V 4 4", "T_cam_model")
        check_shape(K, "V 3 3", "K", sizes)
        check_shape(dist_maps, "V H W", "dist_maps", sizes)
        check_shape(view_weights, "V", "view_weights", sizes)
        if occluder_depth is not None:
            check_shape(occluder_depth, "V H W", "occluder_depth", sizes)
        device = T_cam_model.device
        B, V = sizes["B"], sizes["V"]
        flat_T = T_cam_model.to(torch.float32).reshape(B * V, 4, 4)
        Ks = K.to(device, torch.float32)
        dist = dist_maps.to(device, torch.float32)
        occ = None if occluder_depth is None else occluder_depth.to(device, torch.float32)
        per_view = self.edge_view_costs(model, flat_T, V, Ks, dist, occ, near)
        return (per_view.view(B, V) * view_weights.to(device, torch.float32)).sum(1)

    @abstractmethod
    def edge_view_costs(self, model: EdgeModel, T: torch.Tensor, V: int, K: torch.Tensor, dist: torch.Tensor,
                        occ: torch.Tensor | None, near: float) -> torch.Tensor:  # fmt: skip
        """Unweighted costs ``(C,)`` float32 of C canvases ``T (C, 4, 4)`` (canvas ``c`` in view ``c % V``) of
        :meth:`edge_costs`' inputs, checked and on one device."""

    @abstractmethod
    def scene_cost(self, meshes: list[RenderMesh], T_cam_model: torch.Tensor, K: torch.Tensor,
                   target_edges: torch.Tensor, dist_maps: torch.Tensor, edge_threshold: float) -> float:  # fmt: skip
        """The symmetric edge distance of a whole placement (what the sweeps and the scene polish judge by,
        :func:`~bop_cender.pose.coverage.torch_scene_cost` says why): all objects rendered together, forward plus
        backward, the mean over the V views (pixels).

        Args:
            meshes: the M placed objects' meshes.
            T_cam_model: ``(V, M, 4, 4)`` their poses in each view's camera frame (mm).
            K: ``(V, 3, 3)``; target_edges: ``(V, H, W)`` bool, the target's binarised curvature; dist_maps: ``(V, H,
                W)`` their distance maps (the device of every step); edge_threshold: raw rendered curvature above
                which a composite pixel is one of its own edges.
        """

    @abstractmethod
    def window_costs(self, window: SceneWindow, T_world_model: np.ndarray) -> np.ndarray:
        """``(m,)`` windowed scene costs (the scene polish, :mod:`bop_cender.pose.scene_polish`: the scene cost in the
        windows of ``window``, pixels) of trial poses ``T_world_model (m, 4, 4)`` of the window's part."""


class TorchBackend(TorchRender, Backend):
    """Torch operators for every computation: the torch atlases (:func:`~bop_cender.pose.cost.atlas_view_costs`),
    the edge proxy's compacted layout on the CPU and its dense one on CUDA
    (:func:`~bop_cender.pose.edge_cost.torch_edge_view_costs`), the scene costs' torch steps after the torch
    pipeline's render.

    Args:
        dense_edges: the edge proxy's layout: dense (True), compacted (False), or by device (None: dense on CUDA).
    """

    def __init__(self, dense_edges: bool | None = None) -> None:
        super().__init__()
        self.dense_edges = dense_edges

    def candidate_view_costs(self, mesh: RenderMesh, T: torch.Tensor, K: torch.Tensor, height: int, width: int,
                             near: float, dist: torch.Tensor, occ: torch.Tensor | None, chunk_pixels: int,
                             workers: int) -> torch.Tensor:  # fmt: skip
        batch = prepare_candidates(mesh, T, K, height, width, near, chunk_pixels, occluder_depth=occ)
        return atlas_view_costs(batch, dist, workers)

    def edge_view_costs(self, model: EdgeModel, T: torch.Tensor, V: int, K: torch.Tensor, dist: torch.Tensor,
                        occ: torch.Tensor | None, near: float) -> torch.Tensor:  # fmt: skip
        dense = T.device.type == "cuda" if self.dense_edges is None else self.dense_edges
        return torch_edge_view_costs(model, T, V, K, dist, occ, near, dense)

    def scene_cost(self, meshes: list[RenderMesh], T_cam_model: torch.Tensor, K: torch.Tensor,
                   target_edges: torch.Tensor, dist_maps: torch.Tensor, edge_threshold: float) -> float:  # fmt: skip
        device = dist_maps.device
        _, H, W = target_edges.shape
        render = render_scene(meshes, T_cam_model.to(device, torch.float32), K.to(device, torch.float32), H, W,
                              backend=self)  # fmt: skip
        return torch_scene_cost(render.normals, dist_maps.to(device), target_edges.to(device), edge_threshold)

    def window_costs(self, window: SceneWindow, T_world_model: np.ndarray) -> np.ndarray:
        m, (h, w) = len(T_world_model), window.size
        render = render_scene([window.mesh], window_poses(window, T_world_model), window.K.repeat(m, 1, 1), h, w,
                              backend=self)  # fmt: skip
        return torch_window_costs(window, render.depth, render.normals, m)


class NumbaBackend(NumbaRender, Backend):
    """numba's compiled loops on the CPU (:mod:`bop_cender.pose.cost_kernel`, :mod:`bop_cender.pose.edge_kernel`,
    :mod:`bop_cender.pose.window_kernel` after the compiled render) and its kernels on CUDA
    (:mod:`bop_cender.pose.cuda_cost`, :mod:`bop_cender.pose.cuda_edge_kernel`,
    :mod:`bop_cender.pose.cuda_window_kernel`, :mod:`bop_cender.render.cuda_render`); :attr:`torch`
    (:class:`TorchBackend`) where they leave a call to torch, and on other devices.

    Args:
        insist: where numba cannot run at all, raise instead of warning once and taking the torch code (the
            backend ``numba`` against ``auto``).
    """

    def __init__(self, insist: bool = False) -> None:
        super().__init__(insist)
        #: The torch code, for what the loops and kernels leave to it.
        self.torch = TorchBackend()

    def candidate_view_costs(self, mesh: RenderMesh, T: torch.Tensor, K: torch.Tensor, height: int, width: int,
                             near: float, dist: torch.Tensor, occ: torch.Tensor | None, chunk_pixels: int,
                             workers: int) -> torch.Tensor:  # fmt: skip
        if T.device.type == "cuda":
            costs = self.kernel_candidate_costs(mesh, T, K, height, width, near, dist, occ)
            if costs is not None:
                return costs
        batch = prepare_candidates(mesh, T, K, height, width, near, chunk_pixels, occluder_depth=occ)
        if self.cpu_loops(T.device):
            from bop_cender.pose.cost_kernel import compiled_candidate_costs  # numba: imported where it is used

            costs = compiled_candidate_costs(batch, dist)
            if costs is not None:
                return costs
            self.near_plane("the compiled render cost")
        return atlas_view_costs(batch, dist, workers)

    def kernel_candidate_costs(self, mesh: RenderMesh, T: torch.Tensor, K: torch.Tensor, height: int, width: int,
                              near: float, dist: torch.Tensor, occ: torch.Tensor | None) -> torch.Tensor | None:  # fmt: skip
        """The cost kernel's unweighted costs; None where the torch atlases are to serve (warned once: the kernel
        cannot run here, or declines a mesh of more than 2^15 faces or a vertex behind the near plane)."""
        from bop_cender.pose import cuda_cost  # numba: imported where it is used

        compute = partial(cuda_cost.cuda_candidate_costs, mesh, T, K, height, width, near, dist, occ)
        if int(mesh.faces.shape[0]) <= 1 << 15:
            return self.run_kernel(cuda_cost.GUARD, compute, "the CUDA cost kernel")
        costs = self.run_kernel(cuda_cost.GUARD, compute, None)
        if costs is None and cuda_cost.GUARD.unavailable() is None:  # declined, not unavailable (warned then)
            self.warn_once(
                "the CUDA cost kernel takes meshes of at most 2^15 faces: larger ones run on the torch atlases"
            )
        return costs

    def edge_view_costs(self, model: EdgeModel, T: torch.Tensor, V: int, K: torch.Tensor, dist: torch.Tensor,
                        occ: torch.Tensor | None, near: float) -> torch.Tensor:  # fmt: skip
        device = T.device
        if device.type == "cpu":
            from bop_cender.pose.edge_kernel import kernel_canvas_costs  # numba: imported where it is used

            view = torch.arange(T.shape[0]) % V
            return kernel_canvas_costs(model, T, view, K, dist, occ, near, SAMPLES_PER_SEGMENT, EDGE_COINCIDENCE_MM)
        if device.type == "cuda":
            from bop_cender.pose import cuda_edge_kernel  # numba: imported where it is used

            view = torch.arange(T.shape[0], device=device) % V
            compute = partial(cuda_edge_kernel.cuda_canvas_costs, model, T, view, K, dist, occ, near,
                              SAMPLES_PER_SEGMENT, EDGE_COINCIDENCE_MM)  # fmt: skip
            costs = self.run_kernel(cuda_edge_kernel.GUARD, compute, None)  # the proxy never declines a call
            if costs is not None:
                return costs
        return self.torch.edge_view_costs(model, T, V, K, dist, occ, near)

    def scene_cost(self, meshes: list[RenderMesh], T_cam_model: torch.Tensor, K: torch.Tensor,
                   target_edges: torch.Tensor, dist_maps: torch.Tensor, edge_threshold: float) -> float:  # fmt: skip
        device = dist_maps.device
        if device.type == "cuda":
            from bop_cender.pose import cuda_window_kernel  # numba: imported where it is used

            compute = partial(cuda_window_kernel.cuda_scene_cost, meshes, T_cam_model, K, target_edges, dist_maps,
                              edge_threshold)  # fmt: skip
            drawn = len(meshes) > 0 and len(target_edges) > 0
            cost = self.run_kernel(cuda_window_kernel.GUARD, compute, "the CUDA scene cost kernel" if drawn else None)
            if cost is not None:
                return cost
        if device.type != "cpu":  # the torch steps, the render too (the kernel declined, or none)
            return self.torch.scene_cost(meshes, T_cam_model, K, target_edges, dist_maps, edge_threshold)
        from bop_cender.pose.window_kernel import window_costs  # numba: imported where it is used

        V = int(T_cam_model.shape[0])
        _, H, W = target_edges.shape
        render = render_scene(meshes, T_cam_model.to(device, torch.float32), K.to(device, torch.float32), H, W,
                              backend=self)  # fmt: skip
        offsets = torch.zeros((V, 2), dtype=torch.int64, device=device)
        total = window_costs(render.depth, render.normals, None, None, dist_maps.to(device), offsets,
                             target_edges.to(device), edge_threshold)  # fmt: skip
        return float(total.mean())

    def window_costs(self, window: SceneWindow, T_world_model: np.ndarray) -> np.ndarray:
        device = window.dist.device
        if device.type == "cuda":
            from bop_cender.pose import cuda_window_kernel  # numba: imported where it is used

            compute = partial(cuda_window_kernel.cuda_window_costs, window, T_world_model)
            drawn = len(window.T_cam_world) > 0
            costs = self.run_kernel(cuda_window_kernel.GUARD, compute, "the CUDA window kernel" if drawn else None)
            if costs is not None:
                return costs
        if device.type != "cpu":  # the torch steps, the render too (the kernel declined, or none)
            return self.torch.window_costs(window, T_world_model)
        from bop_cender.pose.window_kernel import window_costs  # numba: imported where it is used

        m, V, (h, w) = len(T_world_model), len(window.T_cam_world), window.size
        render = render_scene([window.mesh], window_poses(window, T_world_model), window.K.repeat(m, 1, 1), h, w,
                              backend=self)  # fmt: skip
        total = window_costs(render.depth, render.normals, window.other_depth, window.other_normals, window.dist,
                             window.offsets, window.target_edges, window.edge_threshold)  # fmt: skip
        return total.view(m, V).mean(1).numpy()


def backend_named(name: str) -> Backend:
    """The backend called ``name`` (``auto``, ``torch`` or ``numba``: the module docstring), one object per name in a
    process, so that its warnings are said once per run.

    Raises:
        ValueError: an unknown name.
    """
    if name not in _BACKENDS:
        raise ValueError(f"unknown backend {name!r}; expected one of {', '.join(BACKEND_NAMES)}")
    return _BACKENDS[name]


_BACKENDS: dict[str, Backend] = {"auto": NumbaBackend(), "torch": TorchBackend(), "numba": NumbaBackend(insist=True)}
