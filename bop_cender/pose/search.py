"""One object's search (paper, Section 2.3): random candidates around its 3D centre, the best refined.

For each object id the target may be: ``poses.candidates.n`` poses, rotations uniform on SO(3) and the model's
centre normally distributed around the 3D centre (:func:`draw_candidates`), then

- ``search_cost="edges"`` (ours): ranked on the edge-point proxy (:func:`rank_on_edges`: a sparse edge model, the
  best re-ranked by the full one), the best few kept apart in rotation (:func:`diverse_starts`) and, with the screen,
  refined briefly first (:func:`edge_search_starts`), then refined on the proxy plus the centre term; the finalists'
  final cost is the paper's render cost plus the centre term;
- ``search_cost="render"`` (the paper's): costed by the render cost at ``candidates.downscale``, the best refined on
  the render cost at full resolution.

The lowest final cost over the object ids wins (a coarse candidate of a similar part can beat a slightly
misaligned one of the right part, so each id is refined before they are compared).
"""

from __future__ import annotations

from functools import partial

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from bop_cender.pose.context import SceneContext
from bop_cender.pose.edge_cost import EdgeModel
from bop_cender.pose.nelder_mead import refine
from bop_cender.pose.problem import Refinement, pose_matrices, render_costs
from bop_cender.pose.types import PlacedObject, PoseTarget


def optimise_object(
    context: SceneContext,
    target: PoseTarget,
    rng: np.random.Generator,
    occluder_depth: torch.Tensor | None = None,
    coarse_occluder_depth: torch.Tensor | None = None,
    incumbent: PlacedObject | None = None,
    finalists: list[PlacedObject] | None = None,
) -> PlacedObject:
    """The best pose of the object at ``target``: random candidates then bounded Nelder-Mead (module docstring).

    Args:
        context: the scene.
        target: the object's 3D centre, view scores and the object ids it may be.
        rng: draws the candidates (:meth:`SceneContext.rng`).
        occluder_depth: ``(V, H, W)`` depth of the objects that hide it, at full resolution (None: none).
        coarse_occluder_depth: the same at ``context.coarse``'s resolution (the render search's candidates).
        incumbent: the object's pose from an earlier sweep, refined as one more start (its evaluations are added
            to the result's).
        finalists: where given, every refined pose of every object id is appended to it (its final cost, 0
            evaluations), so that a caller can judge them otherwise (a further sweep judges them by the scene).

    Returns:
        The pose of lowest final cost over the object ids, with the evaluations of all of them.
    """
    config = context.config
    R, centers = draw_candidates(context, target, rng)
    best: PlacedObject | None = None
    evaluations = 0 if incumbent is None else incumbent.evaluations
    for obj_id in target.obj_ids:
        problem = Refinement(context, target, obj_id, occluder_depth)
        T = pose_matrices(R, centers, problem.center_model)
        extra = incumbent.T_world_model[None] if incumbent is not None and incumbent.obj_id == obj_id else None
        if config.search_cost == "edges":
            T_ref, c_ref, fev = search_on_edges(problem, T, context.edge_models(obj_id), extra)
        else:
            T_ref, c_ref, fev = search_on_render(problem, T, coarse_occluder_depth, extra)
        evaluations += fev
        if finalists is not None:
            finalists += [PlacedObject(obj_id, T_ref[j], float(c_ref[j]), 0) for j in range(len(T_ref))]
        k = int(np.argmin(c_ref))
        if best is None or c_ref[k] < best.cost:
            best = PlacedObject(obj_id, T_ref[k], float(c_ref[k]), 0)
    assert best is not None
    return PlacedObject(best.obj_id, best.T_world_model, best.cost, evaluations)


def draw_candidates(
    context: SceneContext, target: PoseTarget, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """``candidates.n`` random rotations ``(n, 3, 3)``, uniform on SO(3), and model centres ``(n, 3)`` (world, mm)
    normally spread by ``candidates.translation_sigma_mm`` around ``target``'s 3D centre (in that order from ``rng``)."""
    cand = context.config.candidates
    R = Rotation.random(cand.n, random_state=rng).as_matrix()
    centers = target.center[None] + rng.normal(0.0, cand.translation_sigma_mm, size=(cand.n, 3))
    return R, centers


def search_on_edges(
    problem: Refinement, T: np.ndarray, model: EdgeModel, extra: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, int]:
    """Candidates ``T (n, 4, 4)`` ranked (:func:`rank_on_edges`) and refined on the edge cost plus the centre term
    from :func:`edge_search_starts` and ``extra (e, 4, 4)`` (an earlier sweep's pose), the finalists then costed
    by the render cost plus the centre term. Returns the finalists' poses ``(k, 4, 4)``, their final costs ``(k,)``
    and the evaluations."""
    pool = rank_on_edges(problem, T, model)
    search_cost = partial(problem.search_cost, model=model)
    starts, fev = edge_search_starts(problem, T[pool], search_cost)
    evaluations = len(T) + len(pool) + fev
    if extra is not None:
        starts = np.concatenate([starts, extra])
    T_ref, _, fev = refine(starts, problem, search_cost)
    evaluations += fev
    final = problem.cost(T_ref) + problem.center_term(T_ref)
    evaluations += len(T_ref)
    return T_ref, final, evaluations


def rank_on_edges(problem: Refinement, T: np.ndarray, model: EdgeModel) -> np.ndarray:
    """Indices of the best of candidates ``T (n, 4, 4)``, best first: ranked by the sparse edge model
    (``candidates.segments``), the best ``candidates.rerank`` (at least ``top_k`` and ``screen.starts``) ranked again
    by the full ``model``; each with the centre term."""
    config, cand = problem.config, problem.config.candidates
    coarse_costs = problem.search_cost(T, model.sparse(cand.segments))
    pool = np.argsort(coarse_costs, kind="stable")[: max(1, cand.rerank, cand.top_k, config.screen.starts)]
    return pool[np.argsort(problem.search_cost(T[pool], model), kind="stable")]


def edge_search_starts(problem: Refinement, ranked: np.ndarray, search_cost) -> tuple[np.ndarray, int]:
    """The starts the edge search refines, from candidates ``ranked (m, 4, 4)`` (best first), and the evaluations
    spent choosing them.

    With the screen (``screen.starts`` > ``candidates.top_k``, and as many candidates), the best ``screen.starts``
    diverse candidates are refined briefly first (``screen.nelder_mead`` on ``search_cost``) and the ``top_k`` lowest
    of them, kept apart in rotation again, go on: a start 10-20 degrees from the true pose costs more than a wrong
    basin's best candidate, and only refining shows which is which, and screened starts often meet in one basin.
    Without it, the ``top_k`` best diverse candidates (:func:`diverse_starts`)."""
    config, cand = problem.config, problem.config.candidates
    top_k, separation, sym = max(1, cand.top_k), cand.start_separation_rad, problem.start_symmetries
    if min(config.screen.starts, len(ranked)) <= top_k:
        return ranked[diverse_starts(ranked, top_k, separation, sym)], 0
    screened = ranked[diverse_starts(ranked, config.screen.starts, separation, sym)]
    T_s, f_s, fev = refine(screened, problem, search_cost, config.screen.nelder_mead)
    refined = T_s[np.argsort(f_s, kind="stable")]
    return refined[diverse_starts(refined, top_k, separation, sym)], fev


def search_on_render(
    problem: Refinement, T: np.ndarray, coarse_occluder_depth: torch.Tensor | None, extra: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, int]:
    """The paper's search: candidates ``T (n, 4, 4)`` costed by the render cost on the coarse maps, the best
    ``candidates.top_k`` (and ``extra``) refined on the full-resolution render cost. Returns the refined poses, their
    render costs (no centre term) and the evaluations."""
    context = problem.context
    coarse = context.coarse
    costs = render_costs(problem.mesh, T, coarse.cameras, coarse.dist, problem.weights, coarse_occluder_depth,
                         context.backend, context.cost_threads)  # fmt: skip
    starts = T[np.argsort(costs, kind="stable")[: max(1, context.config.candidates.top_k)]]
    starts = starts if extra is None else np.concatenate([starts, extra])
    T_ref, c_ref, fev = refine(starts, problem)
    return T_ref, c_ref, fev + len(T)


def diverse_starts(T: np.ndarray, k: int, separation_rad: float, symmetries: np.ndarray | None = None) -> np.ndarray:
    """Indices of up to ``k`` of the poses ``T (n, 4, 4)`` (best first): greedily, each one whose rotation
    differs from every pose taken before by more than ``separation_rad`` (0: the first k), topped up in
    order when too few differ. With ``symmetries (S, 3, 3)`` (the object's symmetry rotations, identity among
    them) the difference is the least over the symmetric copies ``R @ S`` of a pose: copies of one pose are not
    diverse starts."""
    if separation_rad <= 0 or len(T) <= 1:
        return np.arange(min(k, len(T)))
    R = T[:, :3, :3]
    S = np.eye(3)[None] if symmetries is None else np.asarray(symmetries, dtype=np.float64).reshape(-1, 3, 3)
    taken = [0]
    for i in range(1, len(T)):
        if len(taken) == k:
            break
        rel = np.einsum("kji,jl->kil", R[taken], R[i])  # R_taken^T R_i
        # cos of the angle between rotations, the nearest symmetric copy of pose i
        cos = (np.einsum("kij,sji->ks", rel, S).max(axis=1) - 1.0) / 2.0
        if np.all(cos < np.cos(separation_rad)):
            taken.append(i)
    rest = [i for i in range(len(T)) if i not in taken][: k - len(taken)]
    return np.array(taken + rest)
