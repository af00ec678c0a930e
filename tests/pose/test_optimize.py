"""Stage 3 on oracle curvature: the cost's shape, occlusion by placed objects, and the optimiser."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).parents[1]))
from method_data import BOX_T_B, gt_of, perturb  # noqa: E402

from bop_cender.pose.backend import backend_named  # noqa: E402
from bop_cender.pose.optimize import (  # noqa: E402
    PlacedObject,
    PoseConfig,
    PoseTarget,
    Refinement,
    SceneCameras,
    _refine_lockstep,
    _refine_scipy,
    optimise_scene,
    view_weights,
)


def cost_of(mesh, T_world_model, cams, dist, occ=None):
    T = np.einsum("vij,njk->nvik", cams.T_cam_world, T_world_model)
    w = torch.full((len(cams.Ks),), 1.0 / len(cams.Ks))
    return backend_named("auto").candidate_costs(mesh, torch.as_tensor(T, dtype=torch.float32), cams.Ks, cams.height,
                                                  cams.width, dist, w, occluder_depth=occ).numpy()  # fmt: skip


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


@pytest.mark.parametrize("refine", [_refine_lockstep, _refine_scipy])
def test_refinement_recovers_a_perturbed_gt_pose(mini, refine):
    ds, scene, meshes, maps, cams, dist = mini
    g = gt_of(scene, 3)
    center_model = ds.models[3].center
    center3d = g.T_world_model[:3, :3] @ center_model + g.T_world_model[:3, 3]
    start = perturb(g.T_world_model, 6.0, 3.0)
    config = PoseConfig(nm_maxfev=300, t_b=BOX_T_B)
    w = torch.full((len(cams.Ks),), 0.25)
    problem = Refinement(center3d + 1.0, center_model, meshes(3), cams, dist, w, None, config)
    T, c, fev = refine(start[None], problem)
    R_err = np.degrees(Rotation.from_matrix(T[0, :3, :3] @ g.T_world_model[:3, :3].T).magnitude())
    t_err = np.linalg.norm(T[0, :3, 3] - g.T_world_model[:3, 3])
    assert R_err < 1.0 and t_err < 1.0, (R_err, t_err)
    assert fev <= 300 + 8


def _targets(ds, scene, cams, offset_mm) -> list[PoseTarget]:
    """One target per GT part, its 3D centre off the true one by ``offset_mm``, either part id allowed."""
    targets = []
    for g in scene.gt:
        if ds.models[g.obj_id].is_target:
            c = g.T_world_model[:3, :3] @ ds.models[g.obj_id].center + g.T_world_model[:3, 3]
            targets.append(PoseTarget(c + np.asarray(offset_mm), np.ones(len(cams.Ks)), (3, 4)))
    return targets


def test_scene_optimisation_places_every_object(mini):
    ds, scene, meshes, maps, cams, dist = mini
    targets = _targets(ds, scene, cams, [1.5, -1.0, 0.5])
    done = []
    placed = optimise_scene(targets, maps.curvature, cams, meshes, lambda i: ds.models[i].center,
                            PoseConfig(n_candidates=400, nm_maxfev=250, t_b=BOX_T_B, passes=2, coverage_weight=1.0),
                            progress=lambda a, b: done.append((a, b)),
                            curvature_scale=1.0)  # fmt: skip
    assert done == [(1, 4), (2, 4), (3, 4), (4, 4)]  # two sweeps over the two objects
    for p in placed:
        g = gt_of(scene, p.obj_id)
        assert np.linalg.norm(p.T_world_model[:3, 3] - g.T_world_model[:3, 3]) < 1.0
    assert sorted(p.obj_id for p in placed) == [3, 4]


def test_the_pose_stage_runs_on_the_device_of_the_curvature(mini, device, monkeypatch):
    """Curvature on ``device``: every render and cost of the search runs there (checked on the renders' inputs)
    and every part is placed within 1 mm; on the CPU an explicit ``device="cpu"`` gives the same bits."""
    from bop_cender.pose import optimize, scene_polish

    ds, scene, meshes, maps, cams, dist = mini
    targets = _targets(ds, scene, cams, [1.0, -0.5, 0.5])
    config = PoseConfig(n_candidates=300, nm_maxfev=150, t_b=BOX_T_B, passes=2, scene_polish_maxfev=20)
    seen: set[str] = set()

    def spy(module, name):
        real = getattr(module, name)

        def wrapped(*args, **kwargs):
            seen.update(a.device.type for a in args if isinstance(a, torch.Tensor))
            return real(*args, **kwargs)

        monkeypatch.setattr(module, name, wrapped)

    auto = backend_named("auto")  # the config's backend: each of its computations sees the inputs' device
    for name in ("candidate_costs", "edge_costs", "scene_cost", "scene_maps", "window_maps"):
        spy(auto, name)
    spy(optimize, "render_scene")
    spy(optimize, "two_sided_costs")
    spy(scene_polish, "render_scene")
    curvature = maps.curvature.to(device)
    placed = optimise_scene(targets, curvature, cams, meshes, lambda i: ds.models[i].center, config,
                            curvature_scale=1.0)  # fmt: skip
    assert seen == {device.type}
    for p in placed:
        g = gt_of(scene, p.obj_id)
        assert np.linalg.norm(p.T_world_model[:3, 3] - g.T_world_model[:3, 3]) < 1.0
    if device.type == "cpu":
        explicit = optimise_scene(targets, maps.curvature.numpy(), cams, meshes, lambda i: ds.models[i].center,
                                  config, curvature_scale=1.0, device="cpu")  # fmt: skip
        for a, b in zip(placed, explicit, strict=True):
            assert a.obj_id == b.obj_id and np.array_equal(a.T_world_model, b.T_world_model) and a.cost == b.cost


def test_scene_acceptance_keeps_a_move_only_where_the_whole_placement_gains(mini, monkeypatch):
    """The second sweep's search is replaced by a known answer: a move off the true place is refused (the
    first sweep's pose is kept, its evaluations counted), a move onto it is taken; with ``acceptance="object"``
    the object's own cost decides instead."""
    from bop_cender.pose import optimize

    ds, scene, meshes, maps, cams, dist = mini
    parts = {g.obj_id: g.T_world_model for g in scene.gt if ds.models[g.obj_id].is_target}
    targets = _targets(ds, scene, cams, [0.0, 0.0, 0.0])
    first = {i: perturb(T, 3.0, 1.0) for i, T in parts.items()}  # the first sweep: near the truth
    proposals: dict[int, np.ndarray] = {}

    def known_answer(target, *args, incumbent=None, **kwargs):
        obj_id = min(parts, key=lambda i: np.linalg.norm(parts[i][:3, 3] - target.center))
        if incumbent is None:
            return PlacedObject(obj_id, first[obj_id], 0.0, 10)
        return PlacedObject(obj_id, proposals[obj_id], -1.0, incumbent.evaluations + 5)  # cheaper by its own cost

    monkeypatch.setattr(optimize, "optimise_object", known_answer)
    monkeypatch.setattr(optimize, "_hidden_pixels_differ", lambda *a: True)
    args = (targets, maps.curvature, cams, meshes, lambda i: ds.models[i].center)
    config = dict(t_b=BOX_T_B, passes=2, scene_polish_maxfev=0)  # the sweeps alone
    proposals.update({i: perturb(T, 25.0, 10.0) for i, T in parts.items()})  # worse for the scene
    refused = optimise_scene(*args, PoseConfig(**config, acceptance="scene"), curvature_scale=1.0)
    for p in refused:
        assert np.array_equal(p.T_world_model, first[p.obj_id]) and p.evaluations == 15 and p.cost == 0.0
    taken_by_object = optimise_scene(*args, PoseConfig(**config, acceptance="object"), curvature_scale=1.0)
    assert all(np.array_equal(p.T_world_model, proposals[p.obj_id]) for p in taken_by_object)
    proposals.update(parts)  # the true poses: better for the scene
    taken = optimise_scene(*args, PoseConfig(**config, acceptance="scene"), curvature_scale=1.0)
    assert all(np.array_equal(p.T_world_model, parts[p.obj_id]) for p in taken)
    assert PoseConfig().passes == 3 and PoseConfig().acceptance == "finalists"  # ours; the paper's is one pass


def test_finalists_acceptance_judges_every_refined_pose_by_the_scene(mini, monkeypatch):
    """A second-sweep search whose own best is off the true place but whose other finalist is the true pose:
    ``acceptance="scene"`` sees only the own best and keeps the first sweep's pose; ``"finalists"`` judges
    every finalist by the scene cost, takes the true one and polishes it (it stays on the truth)."""
    from bop_cender.pose import optimize

    ds, scene, meshes, maps, cams, dist = mini
    parts = {g.obj_id: g.T_world_model for g in scene.gt if ds.models[g.obj_id].is_target}
    targets = _targets(ds, scene, cams, [0.0, 0.0, 0.0])
    first = {i: perturb(T, 12.0, 6.0) for i, T in parts.items()}  # the first sweep: off the truth
    own_best = {i: perturb(T, 25.0, 10.0) for i, T in parts.items()}  # what each search ranks first

    def search(target, *args, incumbent=None, finalists=None, **kwargs):
        obj_id = min(parts, key=lambda i: np.linalg.norm(parts[i][:3, 3] - target.center))
        if incumbent is None:
            return PlacedObject(obj_id, first[obj_id], 0.0, 10)
        if finalists is not None:
            finalists += [PlacedObject(obj_id, own_best[obj_id], -1.0, 0), PlacedObject(obj_id, parts[obj_id], 0.5, 0)]
        return PlacedObject(obj_id, own_best[obj_id], -1.0, incumbent.evaluations + 5)

    monkeypatch.setattr(optimize, "optimise_object", search)
    monkeypatch.setattr(optimize, "_hidden_pixels_differ", lambda *a: True)
    args = (targets, maps.curvature, cams, meshes, lambda i: ds.models[i].center)
    config = dict(t_b=BOX_T_B, passes=2, polish_maxfev=60, scene_polish_maxfev=0)  # the sweeps alone
    kept = optimise_scene(*args, PoseConfig(**config, acceptance="scene"), curvature_scale=1.0)
    assert all(np.array_equal(p.T_world_model, first[p.obj_id]) for p in kept)
    chosen = optimise_scene(*args, PoseConfig(**config, acceptance="finalists"), curvature_scale=1.0)
    for p in chosen:
        T = parts[p.obj_id]
        R_err = np.degrees(Rotation.from_matrix(p.T_world_model[:3, :3] @ T[:3, :3].T).magnitude())
        assert R_err < 0.5 and np.linalg.norm(p.T_world_model[:3, 3] - T[:3, 3]) < 0.5, (p.obj_id, R_err)
        assert p.evaluations > 15  # the polish's evaluations are counted


def test_view_weights():
    np.testing.assert_allclose(view_weights(np.array([1.0, 3.0, 0.0]), "center"), [0.25, 0.75, 0.0])
    np.testing.assert_allclose(view_weights(np.array([1.0, 3.0]), "uniform"), [0.5, 0.5])
    np.testing.assert_allclose(view_weights(np.zeros(4), "center"), 0.25)
    with pytest.raises(ValueError):
        view_weights(np.ones(2), "bogus")


def test_a_candidate_that_duplicates_a_placed_object_costs_the_most(mini):
    """Where a candidate's surface coincides with a placed object's, the placed object is what the image
    shows: the same part found twice draws nothing and ranks last, instead of fitting perfectly."""
    from bop_cender.pose.optimize import _occluder_depth

    ds, scene, meshes, maps, cams, dist = mini
    T = gt_of(scene, 3).T_world_model
    placed = _occluder_depth([PlacedObject(3, T, 0.0, 0)], cams, meshes, backend_named("auto"))
    free = cost_of(meshes(3), T[None], cams, dist)
    twice = cost_of(meshes(3), T[None], cams, dist, placed)
    assert free[0] < 0.1
    assert twice[0] == pytest.approx(np.hypot(cams.height, cams.width), rel=1e-5)
    # the other part, beside it, keeps its fit
    other = gt_of(scene, 4).T_world_model[None]
    assert cost_of(meshes(4), other, cams, dist, placed)[0] < 1.0


def test_diverse_starts_are_positions_in_the_ranking_best_first_and_apart_in_rotation():
    from bop_cender.pose.optimize import _diverse

    def pose(deg):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("z", deg, degrees=True).as_matrix()
        return T

    ranked = np.stack([pose(d) for d in (0, 5, 40, 42, 90)])  # best first
    np.testing.assert_array_equal(_diverse(ranked, 3, np.radians(20)), [0, 2, 4])
    np.testing.assert_array_equal(_diverse(ranked, 3, 0.0), [0, 1, 2])
    # too few far apart: topped up in ranking order
    np.testing.assert_array_equal(_diverse(ranked[:2], 2, np.radians(20)), [0, 1])


def test_an_unknown_named_setting_is_one_config_error_before_any_scene():
    from bop_cender.errors import ConfigError
    from bop_cender.method import CenDerNetConfig

    with pytest.raises(ConfigError, match="poses.search_cost: expected one of edges, render"):
        CenDerNetConfig.for_dataset("dimo").with_settings(["poses.search_cost=bogus"])
    with pytest.raises(ConfigError, match="poses.view_weights"):
        PoseConfig(view_weights="median")


def test_a_later_sweep_keeps_the_incumbent_pose_when_no_candidate_is_better(mini):
    """An object searched again in a later sweep starts from its previous pose as well as from the
    candidates: with candidates too few to find it, the result is still the incumbent's basin."""
    from bop_cender.pose.optimize import CostMaps, PlacedObject, optimise_object

    ds, scene, meshes, maps, cams, dist = mini
    g = gt_of(scene, 3)
    center3d = g.T_world_model[:3, :3] @ ds.models[3].center + g.T_world_model[:3, 3]
    target = PoseTarget(center3d, np.ones(len(cams.Ks)), (3,))
    edges = maps.curvature > BOX_T_B
    fine = (CostMaps(cams, dist, edges), None)
    config = PoseConfig(n_candidates=3, rerank=3, top_k=1, t_b=BOX_T_B, polish_maxfev=0)
    incumbent = PlacedObject(3, perturb(g.T_world_model, 4.0, 1.5), 9.0, 123)
    found = optimise_object(target, fine, fine, meshes, lambda i: ds.models[i].center, config,
                            np.random.default_rng(5), edge_threshold=BOX_T_B, incumbent=incumbent)  # fmt: skip
    assert np.linalg.norm(found.T_world_model[:3, 3] - g.T_world_model[:3, 3]) < 1.0
    assert found.evaluations > 123  # the incumbent's evaluations carried over
    alone = optimise_object(target, fine, fine, meshes, lambda i: ds.models[i].center, config,
                            np.random.default_rng(5), edge_threshold=BOX_T_B)  # fmt: skip
    assert found.cost <= alone.cost


def _search_setup(mini):
    """``(dataset, meshes, the target of object 3 at its GT centre, full-resolution maps without occluders)``."""
    from bop_cender.pose.optimize import CostMaps

    ds, scene, meshes, maps, cams, dist = mini
    g = gt_of(scene, 3)
    center3d = g.T_world_model[:3, :3] @ ds.models[3].center + g.T_world_model[:3, 3]
    target = PoseTarget(center3d, np.ones(len(cams.Ks)), (3,))
    return ds, meshes, target, (CostMaps(cams, dist, maps.curvature > BOX_T_B), None)


def test_screening_refines_more_starts_briefly_and_continues_the_best(mini, monkeypatch):
    """With screen_starts > top_k the edge search first refines screen_starts diverse starts for screen_maxfev
    evaluations, then the top_k best of them (by their refined cost) for nm_maxfev; without it, top_k starts
    once (screen_starts 0; the default is 8). Where the right basin's best candidate ranks below a wrong one's, only
    refining tells them apart."""
    from bop_cender.pose import optimize
    from bop_cender.pose.optimize import optimise_object

    ds, meshes, target, fine = _search_setup(mini)
    calls = []
    original = optimize._refine_lockstep

    def recording(starts, problem, cost=None):
        out = original(starts, problem, cost)
        calls.append((len(starts), problem.config.nm_maxfev, starts.copy(), out[0], out[1]))
        return out

    monkeypatch.setattr(optimize, "_refine_lockstep", recording)
    common = dict(n_candidates=64, rerank=32, top_k=2, t_b=BOX_T_B, nm_maxfev=40, start_separation_rad=0.0)
    optimise_object(target, fine, fine, meshes, lambda i: ds.models[i].center,
                    PoseConfig(**common, screen_starts=6, screen_maxfev=10), np.random.default_rng(1),
                    edge_threshold=BOX_T_B)  # fmt: skip
    (n1, fev1, _, screened, screened_costs), (n2, fev2, continued, _, _) = calls
    assert (n1, fev1, n2, fev2) == (6, 10, 2, 40)
    # the continued starts are the screen's two best refined poses
    np.testing.assert_array_equal(continued, screened[np.argsort(screened_costs, kind="stable")[:2]])
    calls.clear()
    optimise_object(target, fine, fine, meshes, lambda i: ds.models[i].center, PoseConfig(**common, screen_starts=0),
                    np.random.default_rng(1), edge_threshold=BOX_T_B)  # fmt: skip
    assert [(n, fev) for n, fev, *_ in calls] == [(2, 40)]


def test_the_search_screen_is_on_for_dimo_and_off_for_tless_layouts_unless_set():
    from dataclasses import asdict

    from bop_cender.method import CenDerNetConfig

    assert CenDerNetConfig.for_dataset("dimo").poses.screen_starts == PoseConfig().screen_starts == 8
    assert CenDerNetConfig.for_dataset("tless").poses.screen_starts == 0
    assert CenDerNetConfig.for_dataset("bop").poses.screen_starts == 0
    assert CenDerNetConfig.for_dataset("tless", screen_starts=5).poses.screen_starts == 5
    assert CenDerNetConfig.for_dataset("tless").with_settings(["poses.screen_starts=6"]).poses.screen_starts == 6
    tless, dimo = asdict(CenDerNetConfig.for_dataset("tless").poses), asdict(PoseConfig())
    assert {k: v for k, v in tless.items() if dimo[k] != v} == {"screen_starts": 0}  # nothing else differs


def test_the_screen_takes_its_starts_even_where_rerank_is_smaller(mini, monkeypatch):
    """The re-ranked pool holds at least screen_starts candidates (rerank 4 < screen 6: still 6 screened)."""
    from bop_cender.pose import optimize
    from bop_cender.pose.optimize import optimise_object

    ds, meshes, target, fine = _search_setup(mini)
    sizes = []
    original = optimize._refine_lockstep
    monkeypatch.setattr(optimize, "_refine_lockstep", lambda s, p, c=None: sizes.append(len(s)) or original(s, p, c))
    config = PoseConfig(n_candidates=64, rerank=4, top_k=2, t_b=BOX_T_B, nm_maxfev=20, screen_starts=6, screen_maxfev=8)
    optimise_object(target, fine, fine, meshes, lambda i: ds.models[i].center, config, np.random.default_rng(1),
                    edge_threshold=BOX_T_B)  # fmt: skip
    assert sizes == [6, 2]


def test_the_screened_starts_that_go_on_are_kept_apart_in_rotation(mini, monkeypatch):
    """After the screen, the top_k that go on are chosen by _diverse from the screened poses ranked by refined cost
    (screened starts often meet in one basin)."""
    from bop_cender.pose import optimize
    from bop_cender.pose.optimize import optimise_object

    ds, meshes, target, fine = _search_setup(mini)
    chosen = []
    original = optimize._diverse

    def recording(T, k, separation):
        out = original(T, k, separation)
        chosen.append((len(T), k, separation, out))
        return out

    monkeypatch.setattr(optimize, "_diverse", recording)
    config = PoseConfig(n_candidates=64, rerank=16, top_k=2, t_b=BOX_T_B, nm_maxfev=20, screen_starts=6, screen_maxfev=8,
                        start_separation_rad=0.3)  # fmt: skip
    optimise_object(target, fine, fine, meshes, lambda i: ds.models[i].center, config, np.random.default_rng(1),
                    edge_threshold=BOX_T_B)  # fmt: skip
    assert [(n, k, sep) for n, k, sep, _ in chosen] == [(16, 6, 0.3), (6, 2, 0.3)]


def test_a_networks_curvature_is_binarised_at_its_own_threshold(monkeypatch):
    """``target_threshold`` (a network's calibrated threshold, carried by its heatmaps) binarises the target
    curvature instead of ``t_b``; without one, ``t_b`` does. Edges at 0.6: lost at t_b = 0.75, kept at 0.5."""
    import bop_cender.pose.optimize as optimize

    class Seen(Exception):
        pass

    seen = []

    def capture(binary):
        seen.append(np.asarray(binary).copy())
        raise Seen

    monkeypatch.setattr(optimize, "distance_maps", capture)
    curvature = torch.zeros(2, 8, 10)
    curvature[:, 3, 2:7] = 0.6
    cameras = SceneCameras(np.stack([np.eye(3)] * 2), np.stack([np.eye(4)] * 2), 8, 10)
    for threshold, expected in ((None, 0), (0.5, 10), (0.59, 10), (0.6, 0)):
        with pytest.raises(Seen):
            optimise_scene([], curvature, cameras, None, None, PoseConfig(), target_threshold=threshold)
        assert int(seen[-1].sum()) == expected, threshold


def test_the_curvature_thresholds_are_checked():
    from bop_cender.errors import ConfigError

    for bad in ({"t_b": 1.0}, {"t_b_network": -0.1}, {"t_b_network": float("nan")}):
        with pytest.raises(ConfigError, match="expected a number in"):
            PoseConfig(**bad)
    assert PoseConfig(t_b_network=0.5).t_b_network == 0.5 and PoseConfig().t_b_network is None
