"""What a whole placement is judged by (ours): the scene cost of all placed objects together, plus their centre terms.

A part moved onto a neighbour's edges costs itself no more, but leaves the edges of its true place unexplained and
hides the neighbour's: only the scene sees that. The sweeps' acceptance and the scene polish judge by
:meth:`SceneJudge.cost` (:meth:`~bop_cender.pose.backend.Backend.scene_cost`: the symmetric edge distance of all objects
rendered together against the target edges).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from bop_cender.pose.backend import Backend
from bop_cender.pose.center_term import center_term
from bop_cender.pose.context import SceneContext
from bop_cender.pose.problem import view_weights
from bop_cender.pose.types import CostMaps, PlacedObject, PoseTarget
from bop_cender.render.mesh import RenderMesh


@dataclass(frozen=True, eq=False)
class SceneJudge:
    """The scene ``context`` and the targets in placement order (``targets[k]`` is that of ``placed[k]``)."""

    context: SceneContext
    targets: Sequence[PoseTarget]

    def cost(self, placed: Sequence[PlacedObject]) -> float:
        """What the sweeps and the scene polish judge ``placed`` by: its scene cost (:func:`placement_cost`) plus,
        with ``poses.center_weight`` > 0, each object's centre term."""
        context = self.context
        cost = placement_cost(placed, context.fine, context.meshes, context.edge_threshold, context.backend)
        weight = context.config.center_weight
        if weight > 0:
            for obj, target in zip(placed, self.targets, strict=True):
                w = view_weights(target.view_scores)
                cost += float(center_term(obj.T_world_model[None], context.model_centers(obj.obj_id),
                                          target.view_scores, target.center_map, w, context.cameras, weight)[0])  # fmt: skip
        return cost


def placement_cost(
    placed: Sequence[PlacedObject],
    maps: CostMaps,
    meshes: Callable[[int], RenderMesh],
    edge_threshold: float,
    backend: Backend,
) -> float:
    """The scene cost (:meth:`~bop_cender.pose.backend.Backend.scene_cost`) of ``placed`` against the full-resolution ``maps`` (pixels;
    ``edge_threshold``: the raw curvature of a rendered pose's own edges)."""
    T_wm = np.stack([p.T_world_model for p in placed])
    T_cm = np.einsum("vij,mjk->vmik", maps.cameras.T_cam_world, T_wm)
    return backend.scene_cost(
        [meshes(p.obj_id) for p in placed],
        torch.as_tensor(T_cm, dtype=torch.float32, device=maps.dist.device),
        torch.as_tensor(maps.cameras.Ks, dtype=torch.float32, device=maps.dist.device),
        maps.edges,
        maps.dist,
        edge_threshold,
    )
