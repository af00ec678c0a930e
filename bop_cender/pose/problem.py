"""One object's fit: what its candidates and refinement are costed against (:class:`Refinement`).

The paper's render cost (:func:`render_costs`: the pose's curvature rendered in every view, its distance to the
target edges) and the edge-point proxy (:meth:`~bop_cender.pose.backend.Backend.edge_costs`) of poses of one object
id at one target, under the occluder depth of the objects placed before it, each view weighted by the target's
center score in it (:func:`view_weights`), plus the centre term (:func:`~bop_cender.pose.center_term.center_term`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import torch

from bop_cender.pose.backend import Backend
from bop_cender.pose.center_term import center_term
from bop_cender.pose.config import PoseConfig
from bop_cender.pose.context import SceneContext
from bop_cender.pose.edge_cost import edge_occluder
from bop_cender.pose.edge_model import EdgeModel
from bop_cender.pose.types import PoseTarget, SceneCameras
from bop_cender.render.mesh import RenderMesh


@dataclass(frozen=True, eq=False)
class Refinement:
    """Object ``obj_id`` at ``target``, costed against the scene's full-resolution maps (``context.fine``) under
    ``occluder_depth (V, H, W)`` (the placed objects' depth; None: nothing hides it)."""

    context: SceneContext
    target: PoseTarget
    obj_id: int
    occluder_depth: torch.Tensor | None = None

    @property
    def config(self) -> PoseConfig:
        return self.context.config

    @property
    def center3d(self) -> np.ndarray:
        """The detected 3D centre ``(3,)`` (world, mm)."""
        return self.target.center

    @cached_property
    def center_model(self) -> np.ndarray:
        """The object's 3D centre ``(3,)`` in model coordinates (mm)."""
        return self.context.model_centers(self.obj_id)

    @cached_property
    def start_symmetries(self) -> np.ndarray | None:
        """The rotations ``(S, 3, 3)`` modulo which the starts of this object are kept apart
        (``candidates.symmetric_separation`` and known symmetries), else None (the plain rotation)."""
        symmetries = self.context.symmetries
        if not self.config.candidates.symmetric_separation or symmetries is None:
            return None
        return np.asarray(symmetries(self.obj_id), dtype=np.float64)

    @property
    def mesh(self) -> RenderMesh:
        return self.context.meshes(self.obj_id)

    @cached_property
    def weights(self) -> torch.Tensor:
        """``(V,)`` float32 view weights (:func:`view_weights`) on the maps' device."""
        w = view_weights(self.target.view_scores)
        return torch.as_tensor(w, dtype=torch.float32, device=self.context.fine.dist.device)

    @cached_property
    def _weights_np(self) -> np.ndarray:
        """``weights`` as float64 NumPy ``(V,)``, once (the centre term reads them at every evaluation)."""
        return self.weights.detach().cpu().double().numpy()

    @cached_property
    def _view_scores(self) -> np.ndarray:
        return np.asarray(self.target.view_scores, dtype=np.float64)

    @cached_property
    def edge_occluder(self) -> torch.Tensor | None:
        """The occluder depth widened for the edge cost (:func:`~bop_cender.pose.edge_cost.edge_occluder`)."""
        return None if self.occluder_depth is None else edge_occluder(self.occluder_depth)

    def center_term(self, T_world_model: np.ndarray) -> np.ndarray:
        """``(n,)`` :func:`~bop_cender.pose.center_term.center_term` of poses ``(n, 4, 4)`` of this object."""
        return center_term(T_world_model, self.center_model, self._view_scores, self.target.center_map,
                           self._weights_np, self.context.cameras, self.config.center_weight)  # fmt: skip

    def cost(self, T_world_model: np.ndarray) -> np.ndarray:
        """``(n,)`` render costs of poses ``(n, 4, 4)`` (pixels)."""
        fine = self.context.fine
        return render_costs(
            self.mesh, T_world_model, fine.cameras, fine.dist, self.weights, self.occluder_depth, self.context.backend
        )

    def search_cost(self, T_world_model: np.ndarray, model: EdgeModel) -> np.ndarray:
        """``(n,)`` what the edge search ranks and refines poses ``(n, 4, 4)`` by: the edge cost plus the centre term."""
        return self.edge_cost(T_world_model, model) + self.center_term(T_world_model)

    def edge_cost(self, T_world_model: np.ndarray, model: EdgeModel) -> np.ndarray:
        """``(n,)`` edge-point costs (:meth:`~bop_cender.pose.backend.Backend.edge_costs`) of poses ``(n, 4, 4)``."""
        fine = self.context.fine
        T_cm = np.einsum("vij,njk->nvik", fine.cameras.T_cam_world, T_world_model)
        out = self.context.backend.edge_costs(
            model,
            torch.as_tensor(T_cm, dtype=torch.float32, device=fine.dist.device),
            torch.as_tensor(fine.cameras.Ks, dtype=torch.float32, device=fine.dist.device),
            fine.dist,
            self.weights,
            self.edge_occluder,
        )
        return out.double().cpu().numpy()


def render_costs(
    mesh: RenderMesh,
    T_world_model: np.ndarray,
    cameras: SceneCameras,
    dist: torch.Tensor,
    weights: torch.Tensor,
    occluder_depth: torch.Tensor | None,
    backend: Backend,
    threads: int = 1,
) -> np.ndarray:
    """``(n,)`` float64 render costs of ``T_world_model (n, 4, 4)`` in all views, by ``backend`` (``threads``: chunk
    threads)."""
    T_cm = np.einsum("vij,njk->nvik", cameras.T_cam_world, T_world_model)
    out = backend.candidate_costs(
        mesh,
        torch.as_tensor(T_cm, dtype=torch.float32, device=dist.device),
        torch.as_tensor(cameras.Ks, dtype=torch.float32, device=dist.device),
        cameras.height,
        cameras.width,
        dist,
        weights,
        occluder_depth=occluder_depth,
        workers=threads,
    )
    return out.double().cpu().numpy()


def view_weights(view_scores: np.ndarray) -> np.ndarray:
    """``(V,)`` weights summing to 1: the per-view center scores (the paper's), equal where they sum to 0."""
    s = np.clip(np.asarray(view_scores, dtype=np.float64), 0.0, None)
    if s.sum() <= 0:
        return np.full(len(s), 1.0 / len(s))
    return s / s.sum()


def pose_matrices(R: np.ndarray, centers_world: np.ndarray, center_model: np.ndarray) -> np.ndarray:
    """``T_world_model (n, 4, 4)`` with rotation ``R (n, 3, 3)`` whose model centre lands on ``centers_world (n, 3)``."""
    n = len(R)
    T = np.zeros((n, 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = centers_world - R @ center_model
    T[:, 3, 3] = 1.0
    return T
