"""One object's search (``pose/search.py``): the candidates, their ranking on the edge proxy, the screen of the
starts, the starts kept apart in rotation, and an earlier sweep's pose as one more start."""

from __future__ import annotations

import sys
from dataclasses import replace
from functools import partial
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).parents[1]))
from method_data import gt_of, perturb, pose_config, pose_context  # noqa: E402

from bop_cender.pose.nelder_mead import refine  # noqa: E402
from bop_cender.pose.problem import Refinement, pose_matrices  # noqa: E402
from bop_cender.pose.search import (  # noqa: E402
    diverse_starts,
    draw_candidates,
    edge_search_starts,
    optimise_object,
    rank_on_edges,
)
from bop_cender.pose.types import PlacedObject, PoseTarget  # noqa: E402


def _target(mini, obj_id=3) -> PoseTarget:
    """The target of object ``obj_id`` at its GT centre, seen equally in every view."""
    ds, scene, meshes, maps, cams, dist = mini
    g = gt_of(scene, obj_id)
    return PoseTarget(g.T_world_model[:3, :3] @ ds.models[obj_id].center + g.T_world_model[:3, 3],
                      np.ones(len(cams.Ks)), (obj_id,))  # fmt: skip


def _ranked(mini, *settings: str, seed: int = 1):
    """``(problem, ranked candidates (m, 4, 4), the search cost)`` of object 3 under ``settings``."""
    context = pose_context(mini, pose_config(*settings))
    target = _target(mini)
    problem = Refinement(context, target, 3)
    R, centers = draw_candidates(context, target, np.random.default_rng(seed))
    T = pose_matrices(R, centers, problem.center_model)
    model = context.edge_models(3)
    return problem, T[rank_on_edges(problem, T, model)], partial(problem.search_cost, model=model)


SCREEN = ("candidates.n=64", "candidates.rerank=32", "candidates.top_k=2", "refine.nelder_mead.maxfev=40")


def test_screening_refines_more_starts_briefly_and_continues_the_best(mini):
    """With screen.starts > top_k the edge search first refines screen.starts diverse starts for the screen's maxfev
    evaluations, and the top_k best of them (by their refined cost) go on; without it, the top_k best candidates.
    Where the right basin's best candidate ranks below a wrong one's, only refining tells them apart."""
    problem, ranked, cost = _ranked(mini, *SCREEN, "candidates.start_separation_rad=0", "screen.starts=6",
                                    "screen.nelder_mead.maxfev=10")  # fmt: skip
    starts, fev = edge_search_starts(problem, ranked, cost)
    screened, screened_costs, expected_fev = refine(ranked[:6], problem, cost, problem.config.screen.nelder_mead)
    assert fev == expected_fev > 0
    np.testing.assert_array_equal(starts, screened[np.argsort(screened_costs, kind="stable")[:2]])
    unscreened, _, _ = _ranked(mini, *SCREEN, "candidates.start_separation_rad=0", "screen.starts=0")
    starts, fev = edge_search_starts(unscreened, ranked, cost)
    assert fev == 0
    np.testing.assert_array_equal(starts, ranked[:2])


def test_the_screen_takes_its_starts_even_where_rerank_is_smaller(mini):
    """The re-ranked pool holds at least screen.starts candidates (rerank 4 < screen 6: still 6 screened)."""
    problem, ranked, cost = _ranked(mini, "candidates.n=64", "candidates.rerank=4", "candidates.top_k=2",
                                    "screen.starts=6", "screen.nelder_mead.maxfev=8")  # fmt: skip
    assert len(ranked) == 6
    problem, ranked, cost = _ranked(mini, "candidates.n=64", "candidates.rerank=4", "candidates.top_k=2",
                                    "screen.starts=0")  # fmt: skip
    assert len(ranked) == 4


def test_the_screened_starts_that_go_on_are_kept_apart_in_rotation(mini):
    """The screen takes its starts apart in rotation from the ranked candidates, and the top_k that go on apart
    from the screened poses ranked by refined cost (screened starts often meet in one basin)."""
    problem, ranked, cost = _ranked(mini, "candidates.n=64", "candidates.rerank=16", "candidates.top_k=2",
                                    "screen.starts=6", "screen.nelder_mead.maxfev=8",
                                    "candidates.start_separation_rad=0.3")  # fmt: skip
    starts, _ = edge_search_starts(problem, ranked, cost)
    screened = ranked[diverse_starts(ranked, 6, 0.3)]
    T_s, f_s, _ = refine(screened, problem, cost, problem.config.screen.nelder_mead)
    refined = T_s[np.argsort(f_s, kind="stable")]
    np.testing.assert_array_equal(starts, refined[diverse_starts(refined, 2, 0.3)])


def test_diverse_starts_are_positions_in_the_ranking_best_first_and_apart_in_rotation():
    def pose(deg):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("z", deg, degrees=True).as_matrix()
        return T

    ranked = np.stack([pose(d) for d in (0, 5, 40, 42, 90)])  # best first
    np.testing.assert_array_equal(diverse_starts(ranked, 3, np.radians(20)), [0, 2, 4])
    np.testing.assert_array_equal(diverse_starts(ranked, 3, 0.0), [0, 1, 2])
    # too few far apart: topped up in ranking order
    np.testing.assert_array_equal(diverse_starts(ranked[:2], 2, np.radians(20)), [0, 1])


def test_diverse_starts_modulo_symmetries_skip_the_symmetric_copies_of_a_start():
    """With an object's symmetry rotations, a pose 60 degrees about the axis of a 6-fold symmetric part is the same
    pose, not a diverse start: the next distinct pose is taken instead."""

    def pose(axis, deg):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler(axis, deg, degrees=True).as_matrix()
        return T

    sixfold = np.stack([Rotation.from_euler("z", 60 * k, degrees=True).as_matrix() for k in range(6)])
    ranked = np.stack([pose("z", 0), pose("z", 60), pose("z", 125), pose("x", 90)])  # best first
    np.testing.assert_array_equal(diverse_starts(ranked, 2, np.radians(20)), [0, 1])
    np.testing.assert_array_equal(diverse_starts(ranked, 2, np.radians(20), sixfold), [0, 3])
    np.testing.assert_array_equal(diverse_starts(ranked, 2, np.radians(20), np.eye(3)[None]), [0, 1])  # none


def test_the_starts_are_kept_apart_modulo_symmetries_only_where_set(mini):
    """``candidates.symmetric_separation`` hands the context's symmetry rotations to the starts (off by default,
    and without symmetries known to the context)."""
    sixfold = np.stack([Rotation.from_euler("z", 60 * k, degrees=True).as_matrix() for k in range(6)])
    target = _target(mini)
    for settings, symmetries, expected in (((), lambda obj_id: sixfold, False),
                                           (("candidates.symmetric_separation=true",), lambda obj_id: sixfold, True),
                                           (("candidates.symmetric_separation=true",), None, False)):  # fmt: skip
        context = replace(pose_context(mini, pose_config(*settings)), symmetries=symmetries)
        got = Refinement(context, target, 3).start_symmetries
        assert (got is not None) == expected
        if expected:
            np.testing.assert_array_equal(got, sixfold)


def test_the_candidates_spread_about_the_target_centre(mini):
    context = pose_context(mini, pose_config("candidates.n=4000", "candidates.translation_sigma_mm=5"))
    target = _target(mini)
    R, centers = draw_candidates(context, target, np.random.default_rng(0))
    assert R.shape == (4000, 3, 3) and centers.shape == (4000, 3)
    np.testing.assert_allclose(np.einsum("nij,nkj->nik", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-9)
    assert np.std(centers - target.center) == pytest.approx(5.0, rel=0.05)
    again = draw_candidates(context, target, np.random.default_rng(0))
    assert np.array_equal(R, again[0]) and np.array_equal(centers, again[1])  # the seed decides


def test_a_later_sweep_keeps_the_incumbent_pose_when_no_candidate_is_better(mini):
    """An object searched again in a later sweep starts from its previous pose as well as from the
    candidates: with candidates too few to find it, the result is still the incumbent's basin."""
    ds, scene, *_ = mini
    g = gt_of(scene, 3)
    context = pose_context(mini, pose_config("candidates.n=3", "candidates.rerank=3", "candidates.top_k=1"))
    target = _target(mini)
    incumbent = PlacedObject(3, perturb(g.T_world_model, 4.0, 1.5), 9.0, 123)
    finalists: list[PlacedObject] = []
    found = optimise_object(context, target, np.random.default_rng(5), incumbent=incumbent, finalists=finalists)
    assert np.linalg.norm(found.T_world_model[:3, 3] - g.T_world_model[:3, 3]) < 1.0
    assert found.evaluations > 123  # the incumbent's evaluations carried over
    alone = optimise_object(context, target, np.random.default_rng(5))
    assert found.cost <= alone.cost
    # every refined start is a finalist (the candidate's and the incumbent's), with its final cost
    assert len(finalists) == 2 and min(f.cost for f in finalists) == found.cost
    assert all(f.evaluations == 0 and f.obj_id == 3 for f in finalists)


def test_the_render_search_refines_the_best_candidates_on_the_render_cost(mini):
    """``search_cost=render`` (the paper's search): candidates costed at half resolution, the best refined on the full
    render cost; its final cost is the render cost (no centre term)."""
    ds, scene, *_ = mini
    g = gt_of(scene, 3)
    config = pose_config("search_cost=render", "refine.nelder_mead.maxfev=250")
    context = pose_context(mini, config)
    assert context.coarse is not context.fine and context.coarse.cameras.height == -(-context.cameras.height // 2)
    found = optimise_object(context, _target(mini), np.random.default_rng(2))
    assert np.linalg.norm(found.T_world_model[:3, 3] - g.T_world_model[:3, 3]) < 1.0
    problem = Refinement(context, _target(mini), 3)
    assert found.cost == pytest.approx(float(problem.cost(found.T_world_model[None])[0]))
