"""The scene cost (what the sweeps and the scene polish judge a whole placement by): forward plus backward."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).parents[1]))
from method_data import BOX_T_B, perturb  # noqa: E402

from bop_cender.pose.backend import backend_named  # noqa: E402
from bop_cender.pose.cost import distance_maps  # noqa: E402


def test_the_scene_cost_is_lowest_with_every_part_in_place(mini):
    """A part moved off its place, or left out, leaves its true edges unexplained: the whole placement costs more."""
    scene_cost = backend_named("auto").scene_cost
    ds, scene, meshes, maps, cams, _ = mini
    parts = [g for g in scene.gt if ds.models[g.obj_id].is_target]
    edges = maps.curvature > BOX_T_B
    dist = torch.as_tensor(distance_maps(edges.numpy()))
    K = torch.as_tensor(cams.Ks, dtype=torch.float32)

    def cost(T_world_models):
        T = np.einsum("vij,mjk->vmik", cams.T_cam_world, np.stack(T_world_models))
        return scene_cost([meshes(g.obj_id) for g in parts], torch.as_tensor(T, dtype=torch.float32), K, edges,
                          dist, BOX_T_B * 1.0)  # fmt: skip

    exact = cost([g.T_world_model for g in parts])
    assert exact < 0.5
    # a part missing from the placement leaves its edges unexplained (the review's counterexample)
    T = np.einsum("vij,mjk->vmik", cams.T_cam_world, np.stack([parts[0].T_world_model]))
    missing = scene_cost([meshes(parts[0].obj_id)], torch.as_tensor(T, dtype=torch.float32), K, edges, dist,
                         BOX_T_B * 1.0)  # fmt: skip
    assert missing > exact + 0.5
    for i in range(len(parts)):
        moved = [perturb(g.T_world_model, 25.0, 4.0) if j == i else g.T_world_model for j, g in enumerate(parts)]
        assert cost(moved) > exact + 0.5
