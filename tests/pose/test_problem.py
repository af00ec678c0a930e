"""One object's fit on oracle curvature: the render cost's shape, occlusion by placed objects, the view weights and
the bounded Nelder-Mead that refines a pose (``pose/problem.py``, ``pose/nelder_mead.py``)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).parents[1]))
from method_data import gt_of, perturb, pose_config, pose_context  # noqa: E402

from bop_cender.pose.backend import backend_named  # noqa: E402
from bop_cender.pose.nelder_mead import refine  # noqa: E402
from bop_cender.pose.occluders import occluder_depth  # noqa: E402
from bop_cender.pose.problem import Refinement, render_costs, view_weights  # noqa: E402
from bop_cender.pose.types import PlacedObject, PoseTarget  # noqa: E402


def cost_of(mesh, T_world_model, cams, dist, occ=None):
    w = torch.full((len(cams.Ks),), 1.0 / len(cams.Ks))
    return render_costs(mesh, T_world_model, cams, dist, w, occ, backend_named("auto"))


def test_cost_is_smallest_at_gt_and_grows_with_the_perturbation(mini):
    ds, scene, meshes, maps, cams, dist = mini
    g = gt_of(scene, 3)
    poses = np.stack([perturb(g.T_world_model, a, s) for a, s in ((0, 0), (2, 1), (5, 3), (10, 6), (20, 12))])
    costs = cost_of(meshes(3), poses, cams, dist)
    assert costs[0] < 0.1
    assert np.all(np.diff(costs) > 0), costs


def test_occluders_hide_the_candidate_only_where_they_are_in_front(mini):
    ds, scene, meshes, maps, cams, dist = mini
    T = gt_of(scene, 4).T_world_model[None]
    free = cost_of(meshes(4), T, cams, dist)
    far = torch.full((len(cams.Ks), cams.height, cams.width), 1e5)
    assert cost_of(meshes(4), T, cams, dist, far) == pytest.approx(free, abs=1e-6)
    # a wall in front of the left half of every image hides part of the object: its curvature there is gone
    wall = torch.zeros((len(cams.Ks), cams.height, cams.width))
    wall[:, :, : cams.width // 2 + 10] = 1.0  # 1 mm from the camera: in front of everything
    hidden = cost_of(meshes(4), T, cams, dist, wall)
    assert hidden != pytest.approx(free, abs=1e-4)


def test_symmetric_equivalent_poses_cost_the_same(mini):
    ds, scene, meshes, maps, cams, dist = mini
    import trimesh

    from bop_cender.render.mesh import prepare_mesh

    box = prepare_mesh(trimesh.creation.box(extents=(40.0, 20.0, 10.0)))
    T = gt_of(scene, 4).T_world_model
    flip = np.eye(4)
    flip[:3, :3] = Rotation.from_euler("z", 180, degrees=True).as_matrix()
    c = cost_of(box, np.stack([T, T @ flip]), cams, dist)
    assert c[0] == pytest.approx(c[1], rel=1e-3, abs=1e-3)


def test_a_candidate_that_duplicates_a_placed_object_costs_the_most(mini):
    """Where a candidate's surface coincides with a placed object's, the placed object is what the image
    shows: the same part found twice draws nothing and ranks last, instead of fitting perfectly."""
    ds, scene, meshes, maps, cams, dist = mini
    T = gt_of(scene, 3).T_world_model
    placed = occluder_depth([PlacedObject(3, T, 0.0, 0)], cams, meshes, backend_named("auto"))
    free = cost_of(meshes(3), T[None], cams, dist)
    twice = cost_of(meshes(3), T[None], cams, dist, placed)
    assert free[0] < 0.1
    assert twice[0] == pytest.approx(np.hypot(cams.height, cams.width), rel=1e-5)
    # the other part, beside it, keeps its fit
    other = gt_of(scene, 4).T_world_model[None]
    assert cost_of(meshes(4), other, cams, dist, placed)[0] < 1.0


def test_refinement_recovers_a_perturbed_gt_pose(mini):
    ds, scene, meshes, maps, cams, dist = mini
    g = gt_of(scene, 3)
    center3d = g.T_world_model[:3, :3] @ ds.models[3].center + g.T_world_model[:3, 3]
    start = perturb(g.T_world_model, 6.0, 3.0)
    context = pose_context(mini, pose_config("refine.nelder_mead.maxfev=300"))
    problem = Refinement(context, PoseTarget(center3d + 1.0, np.ones(len(cams.Ks)), (3,)), 3)
    T, c, fev = refine(start[None], problem)
    R_err = np.degrees(Rotation.from_matrix(T[0, :3, :3] @ g.T_world_model[:3, :3].T).magnitude())
    t_err = np.linalg.norm(T[0, :3, 3] - g.T_world_model[:3, 3])
    assert R_err < 1.0 and t_err < 1.0, (R_err, t_err)
    assert fev <= 300 + 8
    assert c[0] == pytest.approx(problem.cost(T)[0])  # the render cost, by default
    np.testing.assert_array_equal(problem.cost(T), cost_of(meshes(3), T, cams, context.fine.dist))  # equal weights


def test_the_refinement_stays_in_its_bounds(mini):
    """A cost that pulls the centre far away: the refined centre stops at ``refine.translation_bound_mm`` about the 3D
    centre (each coordinate), and the evaluations stop at the run's ``maxfev``."""
    from bop_cender.pose.config import NelderMead

    ds, scene, meshes, maps, cams, dist = mini
    g = gt_of(scene, 3)
    center3d = g.T_world_model[:3, :3] @ ds.models[3].center + g.T_world_model[:3, 3]
    problem = Refinement(pose_context(mini), PoseTarget(center3d, np.ones(len(cams.Ks)), (3,)), 3)
    far = center3d + 1000.0

    def pull(T):
        return np.linalg.norm(T[:, :3, :3] @ ds.models[3].center + T[:, :3, 3] - far, axis=1)

    T, _, fev = refine(g.T_world_model[None], problem, pull, NelderMead(maxfev=200, xatol=1e-6, fatol=1e-6))
    centre = T[0, :3, :3] @ ds.models[3].center + T[0, :3, 3]
    np.testing.assert_allclose(centre - center3d, np.full(3, 20.0), atol=1e-6)  # the bound, 20 mm
    assert fev <= 200 + 8


def test_view_weights():
    np.testing.assert_allclose(view_weights(np.array([1.0, 3.0, 0.0])), [0.25, 0.75, 0.0])
    np.testing.assert_allclose(view_weights(np.array([-1.0, 3.0])), [0.0, 1.0])
    np.testing.assert_allclose(view_weights(np.zeros(4)), 0.25)  # no view scores: equal weights
