"""A scene's stage 3 (``pose/sweeps.py``): every object placed, on the curvature's device, the further sweeps' choice
by the whole scene, the scene polish's passes, and each placed object judged beside its own target."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).parents[1]))
from method_data import gt_of, perturb, pose_config, pose_context, target_parts  # noqa: E402

from bop_cender.pose import sweeps  # noqa: E402
from bop_cender.pose.config import PoseConfig  # noqa: E402
from bop_cender.pose.context import scene_context  # noqa: E402
from bop_cender.pose.judge import SceneJudge  # noqa: E402
from bop_cender.pose.sweeps import choose_by_scene, optimise_scene  # noqa: E402
from bop_cender.pose.types import PlacedObject, PoseTarget, SceneCameras  # noqa: E402


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
    config = pose_config("candidates.n=400", "refine.nelder_mead.maxfev=250", "sweeps.passes=2")
    placed = optimise_scene(pose_context(mini, config), targets, progress=lambda a, b: done.append((a, b)))
    assert done == [(1, 4), (2, 4), (3, 4), (4, 4)]  # two sweeps over the two objects
    for p in placed:
        g = gt_of(scene, p.obj_id)
        assert np.linalg.norm(p.T_world_model[:3, 3] - g.T_world_model[:3, 3]) < 1.0
    assert sorted(p.obj_id for p in placed) == [3, 4]


def test_the_pose_stage_runs_on_the_device_of_the_curvature(mini, device, monkeypatch):
    """Curvature on ``device``: every render and cost of the search runs there (checked on the renders' inputs)
    and every part is placed within 1 mm; on the CPU an explicit ``device="cpu"`` gives the same bits."""
    from bop_cender.pose.backend import backend_named

    ds, scene, meshes, maps, cams, dist = mini
    targets = _targets(ds, scene, cams, [1.0, -0.5, 0.5])
    config = pose_config("candidates.n=300", "sweeps.passes=2", "scene_polish.nelder_mead.maxfev=20")
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
    centers = lambda i: ds.models[i].center  # noqa: E731
    context = scene_context(maps.curvature.to(device), cams, meshes, centers, config, curvature_scale=1.0)
    placed = optimise_scene(context, targets)
    assert seen == {device.type}
    for p in placed:
        g = gt_of(scene, p.obj_id)
        assert np.linalg.norm(p.T_world_model[:3, 3] - g.T_world_model[:3, 3]) < 1.0
    if device.type == "cpu":
        explicit = scene_context(maps.curvature.numpy(), cams, meshes, centers, config, curvature_scale=1.0,
                                 device="cpu")  # fmt: skip
        for a, b in zip(placed, optimise_scene(explicit, targets), strict=True):
            assert a.obj_id == b.obj_id and np.array_equal(a.T_world_model, b.T_world_model) and a.cost == b.cost


def _judged(mini, config=None):
    """``(parts, targets in placement order, judge)`` of the fixture's two parts at their GT centres."""
    ds, scene, meshes, maps, cams, dist = mini
    parts = target_parts(ds, scene)
    ids = sorted(parts)
    targets = [PoseTarget(parts[i][:3, :3] @ ds.models[i].center + parts[i][:3, 3], np.ones(len(cams.Ks)), (i,))
               for i in ids]  # fmt: skip
    return parts, ids, SceneJudge(pose_context(mini, config), targets)


def test_a_later_sweep_keeps_a_move_only_where_the_whole_placement_gains(mini):
    """A further sweep's search whose only finalist is a move off the true place is refused (the current pose is
    kept, the new search's evaluations counted) though it is cheaper by the object's own cost; a move onto the true
    place is taken."""
    parts, ids, judge = _judged(mini)
    placed = [PlacedObject(i, perturb(parts[i], 3.0, 1.0), 0.0, 10) for i in ids]  # the first sweep: near the truth
    now = judge.cost(placed)
    off = PlacedObject(ids[1], perturb(parts[ids[1]], 25.0, 10.0), -1.0, 15)  # cheaper by its own cost
    kept, cost = choose_by_scene(placed, 1, off, [dataclasses.replace(off, evaluations=0)], now, judge.cost)
    assert kept.T_world_model is placed[1].T_world_model and kept.cost == 0.0 and kept.evaluations == 15
    assert cost == now
    onto = PlacedObject(ids[1], parts[ids[1]], 0.4, 15)
    taken, cost = choose_by_scene(placed, 1, onto, [dataclasses.replace(onto, evaluations=0)], now, judge.cost)
    assert np.array_equal(taken.T_world_model, parts[ids[1]]) and taken.cost == 0.4 and taken.evaluations == 15
    assert cost < now and cost == judge.cost([placed[0], taken])
    assert PoseConfig().sweeps.passes == 3  # ours; the paper's is one pass


def test_every_refined_finalist_is_judged_by_the_scene(mini):
    """A further sweep's search whose own best is off the true place but whose other finalist is the true pose:
    every finalist is judged by the scene cost, and the true one is taken."""
    parts, ids, judge = _judged(mini)
    placed = [PlacedObject(i, perturb(parts[i], 12.0, 6.0), 0.0, 10) for i in ids]  # the first sweep: off the truth
    now = judge.cost(placed)
    own_best = PlacedObject(ids[0], perturb(parts[ids[0]], 25.0, 10.0), -1.0, 15)
    pool = [dataclasses.replace(own_best, evaluations=0), PlacedObject(ids[0], parts[ids[0]], 0.5, 0)]
    chosen, cost = choose_by_scene(placed, 0, own_best, pool, now, judge.cost)
    assert np.array_equal(chosen.T_world_model, parts[ids[0]]) and chosen.cost == 0.5 and chosen.evaluations == 15
    assert cost < now
    # ties keep the current pose
    same, cost = choose_by_scene(placed, 0, own_best, [placed[0]], now, judge.cost)
    assert same is not placed[0] and same.T_world_model is placed[0].T_world_model and cost == now


def _known_search(parts):
    """A search that places the part nearest a target's centre at its GT pose, cost 0, 1 evaluation."""

    def search(context, target, *args, **kwargs):
        obj_id = min(parts, key=lambda i: np.linalg.norm(parts[i][:3, 3] - target.center))
        return PlacedObject(obj_id, parts[obj_id], 0.0, 1)

    return search


def test_optimise_scene_runs_the_scene_polish_only_when_asked(mini, monkeypatch):
    ds, scene, meshes, maps, cams, dist = mini
    parts = target_parts(ds, scene)
    calls = []
    monkeypatch.setattr(sweeps, "optimise_object", _known_search(parts))
    monkeypatch.setattr(sweeps, "polish_on_scene", lambda placed, *a, **k: calls.append(len(placed)) or placed)
    targets = [PoseTarget(T[:3, 3], np.ones(len(cams.Ks)), (i,)) for i, T in parts.items()]

    def run(*settings):
        return optimise_scene(pose_context(mini, pose_config("sweeps.passes=1", *settings)), targets)

    run("scene_polish.nelder_mead.maxfev=0")
    assert calls == []
    assert PoseConfig().scene_polish.nelder_mead.maxfev == 100 and PoseConfig().center_weight == 1.0  # ours
    run("scene_polish.nelder_mead.maxfev=10")
    assert calls == [2]  # two passes asked (ours), but the first kept no new pose: the second would repeat it
    moved = []

    def moving(placed, judge, scene_now=None):  # every pass moves every part a little
        moved.append(scene_now)
        return [dataclasses.replace(p, T_world_model=p.T_world_model + 1e-3) for p in placed]

    monkeypatch.setattr(sweeps, "polish_on_scene", moving)
    run("scene_polish.nelder_mead.maxfev=10", "scene_polish.passes=3")
    assert len(moved) == 3 and moved[1:] == [None, None]  # later passes judge the placement afresh
    moved.clear()
    monkeypatch.setattr(sweeps, "polish_on_scene", lambda placed, judge, scene_now=None: moved.append(1) or [
        dataclasses.replace(p, T_world_model=p.T_world_model.copy()) for p in placed])  # fmt: skip
    run("scene_polish.nelder_mead.maxfev=10", "scene_polish.passes=3")
    assert len(moved) == 1  # copies of the same poses: nothing moved, judged by value


def test_the_judge_and_the_polish_pair_each_placed_object_with_its_own_target(mini, monkeypatch):
    """Objects are placed most visible first, so ``placed[k]`` is not ``targets[k]``: the scene judge and the
    polish must see each object beside its own target (its centre and centre map)."""
    ds, scene, meshes, maps, cams, dist = mini
    parts = target_parts(ds, scene)
    ids = sorted(parts)
    centre = {i: T[:3, :3] @ ds.models[i].center + T[:3, 3] for i, T in parts.items()}
    # the first target is the less visible one: it is placed second
    targets = [PoseTarget(centre[ids[0]], np.full(len(cams.Ks), 0.2), (ids[0],), maps.center[:, 0].numpy()),
               PoseTarget(centre[ids[1]], np.full(len(cams.Ks), 0.9), (ids[1],), maps.center[:, 0].numpy())]  # fmt: skip
    monkeypatch.setattr(sweeps, "optimise_object",
                        lambda context, target, *a, **k: PlacedObject(target.obj_ids[0], parts[target.obj_ids[0]],
                                                                      0.0, 1))  # fmt: skip
    monkeypatch.setattr(sweeps, "hidden_pixels_differ", lambda *a: True)  # every further search runs
    seen = []

    def judged(judge, placed):
        seen.append([(p.obj_id, t.obj_ids[0]) for p, t in zip(placed, judge.targets, strict=True)])
        return 0.0

    monkeypatch.setattr(SceneJudge, "cost", judged)
    monkeypatch.setattr(sweeps, "polish_on_scene", lambda placed, judge, *a, **k: judged(judge, placed) or placed)
    config = pose_config("sweeps.passes=2", "scene_polish.nelder_mead.maxfev=10")
    placed = optimise_scene(pose_context(mini, config), targets)
    assert [p.obj_id for p in placed] == [ids[1], ids[0]]  # most visible first
    assert len(seen) == 4 and all(pair == [(ids[1], ids[1]), (ids[0], ids[0])] for pair in seen)


def test_a_networks_curvature_is_binarised_at_its_own_threshold():
    """``target_threshold`` (a network's calibrated threshold, carried by its heatmaps) binarises the target
    curvature instead of ``t_b``; without one, ``t_b`` does. Edges at 0.6: lost at t_b = 0.75, kept at 0.5."""
    curvature = torch.zeros(2, 8, 10)
    curvature[:, 3, 2:7] = 0.6
    cameras = SceneCameras(np.stack([np.eye(3)] * 2), np.stack([np.eye(4)] * 2), 8, 10)
    for threshold, expected in ((None, 0), (0.5, 10), (0.59, 10), (0.6, 0)):
        context = scene_context(curvature, cameras, None, None, PoseConfig(), target_threshold=threshold)
        assert int(context.fine.edges.sum()) == expected, threshold
    assert scene_context(curvature, cameras, None, None, PoseConfig(t_b=0.5)).fine.edges.sum() == 10
