"""The scene polish (``pose/polish.py``): a slightly wrong part moves onto its true pose, only where the whole scene
gains, stopping at the polish's own tolerances."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).parents[1]))
from method_data import BOX_T_B, full_scene_cost, perturb, pose_config, pose_context, target_parts  # noqa: E402

from bop_cender.pose.backend import backend_named  # noqa: E402
from bop_cender.pose.judge import SceneJudge  # noqa: E402
from bop_cender.pose.polish import polish_on_scene  # noqa: E402
from bop_cender.pose.types import PlacedObject, PoseTarget  # noqa: E402


def _targets(ds, cams, poses: dict[int, np.ndarray]) -> list[PoseTarget]:
    return [PoseTarget(T[:3, :3] @ ds.models[i].center + T[:3, 3], np.ones(len(cams.Ks)), (i,))
            for i, T in poses.items()]  # fmt: skip


def test_polish_on_scene_moves_a_slightly_wrong_part_to_its_true_pose(mini):
    ds, scene, meshes, maps, cams, dist = mini
    edges = maps.curvature > BOX_T_B
    parts = target_parts(ds, scene)
    ids = sorted(parts)
    start = {ids[0]: parts[ids[0]], ids[1]: perturb(parts[ids[1]], 3.0, 1.5)}
    placed = [PlacedObject(i, start[i], 1.0, 7) for i in ids]
    context = pose_context(mini, pose_config("scene_polish.nelder_mead.maxfev=150"))
    polished = polish_on_scene(placed, SceneJudge(context, _targets(ds, cams, start)))
    moved = polished[1]
    T = parts[ids[1]]
    R_err = np.degrees(Rotation.from_matrix(moved.T_world_model[:3, :3] @ T[:3, :3].T).magnitude())
    assert R_err < 1.0 and np.linalg.norm(moved.T_world_model[:3, 3] - T[:3, 3]) < 0.5, R_err
    assert moved.evaluations > 7 and moved.cost != 1.0  # its evaluations counted, its cost that of the new pose
    before = full_scene_cost(meshes, start, cams, edges, dist)
    after = full_scene_cost(meshes, {p.obj_id: p.T_world_model for p in polished}, cams, edges, dist)
    assert after < before
    # the part already at its true pose stays there (a polish never makes the scene worse)
    R0 = np.degrees(Rotation.from_matrix(polished[0].T_world_model[:3, :3] @ parts[ids[0]][:3, :3].T).magnitude())
    assert R0 < 0.5 and np.linalg.norm(polished[0].T_world_model[:3, 3] - parts[ids[0]][:3, 3]) < 0.3


def test_scene_polish_stops_at_its_own_tolerances(mini):
    """The polish's Nelder-Mead stops where its simplex is within scene_polish.nelder_mead's xatol / fatol (loose:
    after a few steps), else at its maxfev; the refinement's tolerances do not decide it."""
    ds, scene, meshes, maps, cams, dist = mini
    parts = target_parts(ds, scene)
    placed = [PlacedObject(i, perturb(parts[i], 2.0, 1.0), 1.0, 0) for i in sorted(parts)]

    def spent(tolerance: str) -> list[int]:
        config = pose_config("scene_polish.nelder_mead.maxfev=60", "refine.nelder_mead.xatol=1e-9",
                             "refine.nelder_mead.fatol=1e-9", f"scene_polish.nelder_mead.xatol={tolerance}",
                             f"scene_polish.nelder_mead.fatol={tolerance}")  # fmt: skip
        judge = SceneJudge(pose_context(mini, config), _targets(ds, cams, parts))
        return [p.evaluations for p in polish_on_scene(placed, judge)]

    tight = spent("1e-9")
    loose = spent("50")
    assert all(n >= 60 for n in tight), tight  # the budget, plus the judge's evaluations
    assert all(n < 20 for n in loose), loose  # the first simplex is already within the tolerances


def test_polish_keeps_a_pose_where_the_scene_does_not_gain(mini, monkeypatch):
    """A window cost that prefers a wrong pose: the full scene cost refuses it and the old pose stays."""
    ds, scene, meshes, maps, cams, dist = mini
    parts = target_parts(ds, scene)
    ids = sorted(parts)
    wrong = {i: perturb(T, 20.0, 8.0) for i, T in parts.items()}
    monkeypatch.setattr(backend_named("auto"), "window_costs",  # the config's backend
                        lambda window, T: np.array([np.linalg.norm(t[:3, 3] - wrong[ids[0]][:3, 3]) for t in T]))  # fmt: skip
    placed = [PlacedObject(i, parts[i], 0.5, 3) for i in ids]
    context = pose_context(mini, pose_config("scene_polish.nelder_mead.maxfev=60"))
    out = polish_on_scene(placed, SceneJudge(context, _targets(ds, cams, parts)))
    for p, q in zip(out, placed, strict=True):
        assert np.array_equal(p.T_world_model, q.T_world_model) and p.cost == 0.5 and p.evaluations > 3
