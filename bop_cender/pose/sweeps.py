"""Stage 3 of CenDerNet (paper, Section 2.3) for one scene: objects placed one by one, then swept again and polished.

:func:`optimise_scene` places the objects in order of decreasing visibility (the aggregated center score of their
3D centre), each searched (:func:`~bop_cender.pose.search.optimise_object`) under the depth of those placed before
it (the paper's reason for the order: an object under another is fitted to what of it is visible). Then, ours:

- further sweeps (``poses.sweeps.passes``; the paper's is one): in the same order each object is searched anew
  (its previous pose one more start) with every other object, as last placed, as its occluder, where those hide
  other pixels of it than when it was fitted; of its refined finalists the one is kept with which the whole
  placement explains the target best (:func:`choose_by_scene`), if better than before. An object placed early
  was fitted without the parts lying on it, and a wrong early pose hid the right one of a later object;
- the scene polish (``poses.scene_polish``, :func:`~bop_cender.pose.polish.polish_on_scene`), pass after pass
  until one keeps nothing.

Each setting's figures: ``results/accuracy/README.md``, "Stage-3 settings: how each default was measured".
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np
import torch

from bop_cender.pose.context import SceneContext
from bop_cender.pose.judge import SceneJudge
from bop_cender.pose.occluders import hidden_pixels_differ, occluder_depth
from bop_cender.pose.polish import polish_on_scene
from bop_cender.pose.search import optimise_object
from bop_cender.pose.types import PlacedObject, PoseTarget


def optimise_scene(
    context: SceneContext, targets: Sequence[PoseTarget], progress: Callable[[int, int], None] | None = None
) -> list[PlacedObject]:
    """Poses of all ``targets`` (one per detected object) in ``context``, most visible first.

    ``progress`` is called with (searches done, searches) after each object of each sweep. Returns one
    :class:`~bop_cender.pose.types.PlacedObject` per target, in the order they were placed."""
    config = context.config
    order = sorted(range(len(targets)), key=lambda i: -float(np.sum(targets[i].view_scores)))
    total = len(targets) * config.sweeps.passes
    placed: list[PlacedObject] = []
    fitted_under: list[torch.Tensor | None] = []  # the occluder depth each object was last fitted under
    for n, i in enumerate(order):
        occ = (
            occluder_depth(placed, context.cameras, context.meshes, context.backend)
            if config.occlusion and placed
            else None
        )
        placed.append(fit(context, targets[i], i, placed, occ, 0))
        fitted_under.append(occ)
        if progress is not None:
            progress(n + 1, total)
    scene_now: float | None = None  # the scene cost of ``placed``, once computed
    judge = SceneJudge(context, [targets[i] for i in order])  # the target of placed[k] is targets[order[k]]
    for sweep in range(1, config.sweeps.passes):
        for idx, i in enumerate(order):
            others = placed[:idx] + placed[idx + 1 :]
            occ = (
                occluder_depth(others, context.cameras, context.meshes, context.backend)
                if config.occlusion and others
                else None
            )
            # where nothing hides it differently from when it was fitted, the same search would be repeated
            if hidden_pixels_differ(
                placed[idx], fitted_under[idx], occ, context.cameras, context.meshes, context.backend
            ):
                pool: list[PlacedObject] = []
                moved = fit(context, targets[i], i, others, occ, sweep, placed[idx], pool)
                if scene_now is None:
                    scene_now = judge.cost(placed)
                placed[idx], scene_now = choose_by_scene(placed, idx, moved, pool, scene_now, judge.cost)
                fitted_under[idx] = occ  # searched under these occluders, kept or not: a third sweep skips alike
            if progress is not None:
                progress(sweep * len(targets) + idx + 1, total)
    if config.scene_polish.nelder_mead.maxfev > 0 and placed:
        for polish_pass in range(config.scene_polish.passes):
            before = [p.T_world_model for p in placed]
            placed = polish_on_scene(placed, judge, scene_now if polish_pass == 0 else None)
            if all(np.array_equal(p.T_world_model, T) for p, T in zip(placed, before, strict=True)):
                break  # nothing moved: another pass would repeat this one
    return placed


def fit(
    context: SceneContext,
    target: PoseTarget,
    index: int,
    others: list[PlacedObject],
    occ: torch.Tensor | None,
    sweep: int,
    incumbent: PlacedObject | None = None,
    finalists: list[PlacedObject] | None = None,
) -> PlacedObject:
    """The search of ``target`` (at ``index`` in the scene's targets) in ``sweep``, under the objects ``others``
    whose full-resolution depth is ``occ`` (rendered again at the render search's coarse resolution where it needs
    them), its candidates drawn by :meth:`SceneContext.rng`; ``incumbent`` and ``finalists`` as in
    :func:`~bop_cender.pose.search.optimise_object`."""
    occ_coarse = occ
    if occ is not None and context.coarse is not context.fine:
        occ_coarse = occluder_depth(others, context.coarse.cameras, context.meshes, context.backend)
    return optimise_object(context, target, context.rng(index, sweep), occ, occ_coarse, incumbent, finalists)


def choose_by_scene(
    placed: list[PlacedObject],
    idx: int,
    moved: PlacedObject,
    pool: list[PlacedObject],
    scene_now: float,
    scene: Callable[[list[PlacedObject]], float],
) -> tuple[PlacedObject, float]:
    """A further sweep's choice for object ``idx``: of its current pose and the new search's refined finalists
    ``pool`` (its best ``moved`` where the pool is empty), the one whose placement has the lowest scene cost
    (``scene``; ``scene_now``: that of ``placed``); ties keep the current pose.

    Why all finalists: where the neighbours are misplaced the object's own cost ranks a wrong finalist first, while
    the scene cost prefers the true pose. Returns the chosen object (its evaluations: all the new search spent) and
    the scene cost."""
    best, best_cost, spent = placed[idx], scene_now, moved.evaluations
    for option in pool or [moved]:
        cost = scene(placed[:idx] + [option] + placed[idx + 1 :])
        if cost < best_cost:
            best, best_cost = option, cost
    return replace(best, evaluations=spent), best_cost
