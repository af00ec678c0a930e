"""One scene's stage-3 context: what every step of the search, the sweeps and the scene polish reads.

:func:`scene_context` binarises the predicted curvature once, turns it into distance maps (full resolution and,
for the render search, ``poses.candidates.downscale`` times coarser), and moves the meshes and edge models to the
pose stage's device on first use. The :class:`SceneContext` it returns is passed to every step instead of the
maps, meshes, model centres, settings and thresholds one by one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from bop_cender.pose.backend import Backend, backend_named
from bop_cender.pose.config import PoseConfig
from bop_cender.pose.cost import distance_maps
from bop_cender.pose.edge_model import EdgeModel, edge_model_of
from bop_cender.pose.types import CostMaps, SceneCameras
from bop_cender.render.curvature import DEFAULT_CURVATURE_SCALE
from bop_cender.render.mesh import RenderMesh


@dataclass(frozen=True, eq=False)
class SceneContext:
    """What stage 3 fits one scene's objects against.

    Attributes:
        config: the settings (a network's centres: already :meth:`~PoseConfig.for_network_centers`).
        fine: full-resolution distance maps ``(V, H, W)``, their cameras and the binarised target ``edges``.
        coarse: the maps that cost the render search's candidates (``fine`` itself for the edge search or a
            ``candidates.downscale`` of 1).
        meshes: the render mesh of an object id, on the pose stage's device.
        edge_models: the edge model of an object id (:func:`~bop_cender.pose.edge_model.edge_model_of`), there too.
        model_centers: the 3D centre ``(3,)`` of an object id in model coordinates (mm, bbox centre).
        edge_threshold: raw curvature above which a rendered pose draws an edge (``t_b`` times the targets' scale),
            for the scene cost.
        backend: the code that computes every render and cost (``config.backend``,
            :func:`~bop_cender.pose.backend.backend_named`: one object per name and process).
        cost_threads: threads that render the chunks of the render search's candidate batch side by side.
        symmetries: the rotations ``(S, 3, 3)`` of an object id's symmetries (identity first; BOP's set,
            :meth:`~bop_cender.data.types.ObjectModel.symmetry_transforms`); None: none known. Read only with
            ``candidates.symmetric_separation``.
    """

    config: PoseConfig
    fine: CostMaps
    coarse: CostMaps
    meshes: Callable[[int], RenderMesh]
    edge_models: Callable[[int], EdgeModel]
    model_centers: Callable[[int], np.ndarray]
    edge_threshold: float
    backend: Backend
    cost_threads: int = 1
    symmetries: Callable[[int], np.ndarray] | None = None

    @property
    def cameras(self) -> SceneCameras:
        """The full-resolution cameras."""
        return self.fine.cameras

    def rng(self, index: int, sweep: int) -> np.random.Generator:
        """The candidates' generator of the target at ``index`` (in the caller's list) in ``sweep`` (0: the first)."""
        seed = self.config.seed
        return np.random.default_rng([seed, index] if sweep == 0 else [seed, index, sweep])


def scene_context(
    curvature: torch.Tensor | np.ndarray,
    cameras: SceneCameras,
    meshes: Callable[[int], RenderMesh],
    model_centers: Callable[[int], np.ndarray],
    config: PoseConfig,
    cost_threads: int = 1,
    edges: Callable[[int], EdgeModel] | None = None,
    curvature_scale: float = DEFAULT_CURVATURE_SCALE,
    target_threshold: float | None = None,
    device: torch.device | str | None = None,
    symmetries: Callable[[int], np.ndarray] | None = None,
) -> SceneContext:
    """The context of a scene whose predicted curvature is ``curvature (V, H, W)`` in [0, 1].

    Args:
        curvature: ``(V, H, W)`` predicted curvature in [0, 1].
        cameras: the views.
        meshes: the renderer's mesh of an object id.
        model_centers: the 3D centre ``(3,)`` of an object id in model coordinates (bbox centre).
        config: see :class:`~bop_cender.pose.config.PoseConfig`.
        cost_threads: threads that render the chunks of the candidate batch side by side
            (:meth:`~bop_cender.pose.backend.Backend.candidate_costs` ``workers``: the same bits; worth it with one
            torch thread and free cores: 258 against 169 calls/s on 2 cores, ``results/bench/run_*``).
        edges: the edge model of an object id, on ``device`` (default: built from ``meshes`` on first use).
        curvature_scale: the targets' curvature scale ``c`` (``curvature`` is ``clip(raw / c, 0, 1)``):
            the scene cost binarises a pose's raw curvature at ``t_b * c``, as a GT target is.
        target_threshold: binarise ``curvature`` here instead of at ``config.t_b`` (a network's curvature:
            :attr:`~bop_cender.net.heatmaps.Heatmaps.curvature_threshold`); None: ``t_b``.
        device: where every render and cost runs (None: the device of ``curvature``, CPU for an array).
            The distance transform runs on the CPU (SciPy), once per scene; its maps, the meshes and the
            edge models then live on ``device`` (``cost_threads`` only counts on the CPU).
        symmetries: see :class:`SceneContext`.
    """
    if device is None:
        device = curvature.device if isinstance(curvature, torch.Tensor) else torch.device("cpu")
    device = torch.device(device)
    meshes = _MeshesOn(meshes, device)
    if edges is None:
        edges = _EdgeModels(meshes, config.edge_segment_mm)
    curv = torch.as_tensor(curvature).detach().to("cpu", torch.float32)
    binary = curv > (config.t_b if target_threshold is None else target_threshold)
    fine = CostMaps(cameras, torch.as_tensor(distance_maps(binary.numpy())).to(device), binary.to(device))
    f = max(1, int(config.candidates.downscale))
    coarse = fine
    if f > 1 and config.search_cost == "render":  # the edge search costs everything on the fine maps
        pooled = torch.nn.functional.max_pool2d(binary[:, None].float(), f, ceil_mode=True)[:, 0] > 0
        coarse = CostMaps(cameras.downscaled(f), torch.as_tensor(distance_maps(pooled.numpy())).to(device))
    edge_threshold = config.t_b * curvature_scale
    backend = backend_named(config.backend)
    return SceneContext(
        config, fine, coarse, meshes, edges, model_centers, edge_threshold, backend, cost_threads, symmetries
    )


class _MeshesOn:
    """The render meshes of object ids on the pose stage's ``device``, each moved there once."""

    def __init__(self, meshes: Callable[[int], RenderMesh], device: torch.device) -> None:
        self.meshes, self.device, self.cache = meshes, device, {}

    def __call__(self, obj_id: int) -> RenderMesh:
        if obj_id not in self.cache:
            mesh = self.meshes(obj_id)
            self.cache[obj_id] = mesh if mesh.device == self.device else mesh.to(self.device)
        return self.cache[obj_id]


class _EdgeModels:
    """Edge models of object ids, built from their render meshes on first use."""

    def __init__(self, meshes: Callable[[int], RenderMesh], segment_mm: float) -> None:
        self.meshes, self.segment_mm, self.cache = meshes, segment_mm, {}

    def __call__(self, obj_id: int) -> EdgeModel:
        if obj_id not in self.cache:
            self.cache[obj_id] = edge_model_of(self.meshes(obj_id), self.segment_mm)
        return self.cache[obj_id]
