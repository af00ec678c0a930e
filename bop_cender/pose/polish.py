"""The scene polish (ours, after the sweeps): each placed object refined on the scene cost, the others fixed.

The sweeps choose between poses refined on the edge proxy; where the proxy's minimum and the scene's differ by a
little (a disc tilted 6 degrees: 5.5 % of its diameter, a miss at the strictest threshold), nothing else moves the
part to the scene's. Each object in turn is refined by Nelder-Mead (``poses.scene_polish.nelder_mead``, within the
search's bounds about its 3D centre) on the scene cost in windows around it
(:func:`~bop_cender.pose.scene_polish.scene_window`), plus its centre term, and kept where the full scene cost
(:class:`~bop_cender.pose.judge.SceneJudge`) falls.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from bop_cender.pose.judge import SceneJudge
from bop_cender.pose.nelder_mead import refine
from bop_cender.pose.occluders import occluder_depth
from bop_cender.pose.problem import Refinement
from bop_cender.pose.scene_polish import SceneWindow, scene_window
from bop_cender.pose.types import PlacedObject


def polish_on_scene(
    placed: list[PlacedObject], judge: SceneJudge, scene_now: float | None = None
) -> list[PlacedObject]:
    """One pass of the scene polish over ``placed`` (in order; ``judge.targets[i]`` is the target of ``placed[i]``).

    The polished pose replaces the old where ``judge.cost`` (the full scene cost plus the centre terms) falls; its
    final cost is then its render cost under all the others plus its centre term, as a sweep's. ``scene_now``:
    ``judge.cost(placed)`` where known. Returns the new placement (every object's evaluations counted)."""
    placed = list(placed)
    if not placed:
        return placed
    context = judge.context
    maps, meshes, config = context.fine, context.meshes, context.config
    if scene_now is None:
        scene_now = judge.cost(placed)
    for idx, obj in enumerate(placed):
        others = placed[:idx] + placed[idx + 1 :]
        window = scene_window(
            meshes(obj.obj_id), obj.T_world_model, [(meshes(o.obj_id), o.T_world_model) for o in others],
            maps.cameras.Ks, maps.cameras.T_cam_world, maps.edges, maps.dist, context.edge_threshold,
            config.scene_polish.margin_px, context.backend,
        )  # fmt: skip
        # the occluders only matter for the final cost of a kept pose: rendered then, not for every part
        problem = Refinement(context, judge.targets[idx], obj.obj_id)
        T_new, _, fev = refine(
            obj.T_world_model[None], problem, _WindowCost(window, problem), config.scene_polish.nelder_mead
        )
        trial = placed[:idx] + [replace(obj, T_world_model=T_new[0])] + placed[idx + 1 :]
        cost = judge.cost(trial)
        spent = obj.evaluations + fev + 1
        if cost < scene_now:
            if config.occlusion and others:
                problem = replace(problem, occluder_depth=occluder_depth(others, maps.cameras, meshes, context.backend))
            final = problem.cost(T_new) + problem.center_term(T_new)
            placed[idx] = PlacedObject(obj.obj_id, T_new[0], float(final[0]), spent + 1)
            scene_now = cost
        else:
            placed[idx] = replace(obj, evaluations=spent)
    return placed


class _WindowCost:
    """What the scene polish minimises for poses ``(n, 4, 4)``: the windowed scene cost plus the centre term."""

    def __init__(self, window: SceneWindow, problem: Refinement) -> None:
        self.window, self.problem = window, problem

    def __call__(self, T_world_model: np.ndarray) -> np.ndarray:
        backend = self.problem.context.backend
        return backend.window_costs(self.window, T_world_model) + self.problem.center_term(T_world_model)
