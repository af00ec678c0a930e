"""What any process that runs scenes does with one scene: :func:`estimate_scene`, and :class:`WorkerState`, what a
worker builds once (dataset, method) and uses for each of its scenes.

Both executors of :mod:`~bop_cender.runner.pool` (this process, a pool of worker processes) and the Ray actors of
:mod:`~bop_cender.runner.ray_executor` run their scenes through these two, so the rows are the same whatever runs
them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path

from bop_cender.data.types import Dataset, ObjectModel, Scene
from bop_cender.errors import BopCenderError
from bop_cender.method import CenDerNet
from bop_cender.runner.build import build_method, open_run_dataset
from bop_cender.runner.request import RunRequest
from bop_cender.runner.shards import SceneOutcome, shard_path


def figure_name(scene_key: str) -> str:
    """The file name of a scene's ``--vis`` figure: its shard's name as a PNG (``/`` of a suffixed key: ``__``)."""
    return shard_path(Path(), scene_key).with_suffix(".png").name


def estimate_scene(
    method: CenDerNet,
    scene: Scene,
    vis_dir: Path | None = None,
    max_views: int | None = None,
    eval_models: Mapping[int, ObjectModel] | None = None,
) -> SceneOutcome:
    """One scene, never raising for a problem of that scene: the error becomes the outcome.

    With ``vis_dir``, the scene's figure is written there as ``<scene key>.png`` (its verdicts judged on
    ``eval_models``, the scorer's, where given: T-LESS estimates on ``models_cad``, scores on ``models_eval``); with
    ``max_views`` only the first K views are given to the method."""
    if max_views is not None:
        scene = replace(scene, views=scene.views[:max_views])
    try:
        output = method.run_scene(scene)
    except (BopCenderError, ValueError, RuntimeError) as e:
        return SceneOutcome(scene.key, None, f"{type(e).__name__}: {e}")
    if vis_dir is not None:
        from bop_cender.data.canvas import on_one_canvas
        from bop_cender.report.scene_figure import scene_figure

        scene_figure(
            output,
            on_one_canvas(scene),  # the views as the method saw them (a multi-sensor capture: one size)
            method.models,
            method.meshes,
            Path(vis_dir) / figure_name(scene.key),
            judge_models=eval_models or None,
        )
    return SceneOutcome(scene.key, output.estimate)


@dataclass
class WorkerState:
    """What a worker (a pool process, a Ray actor) builds once and uses for each of its scenes."""

    request: RunRequest
    dataset: Dataset
    method: CenDerNet

    @classmethod
    def build(cls, request: RunRequest) -> WorkerState:
        """The dataset opened and the method built, its weights read: once per worker, not once per scene."""
        dataset = open_run_dataset(request)
        return cls(request, dataset, build_method(request, dataset))

    def estimate(self, key: str) -> SceneOutcome:
        """Scene ``key`` of the dataset, as :func:`estimate_scene` gives it."""
        request, dataset = self.request, self.dataset
        return estimate_scene(self.method, dataset.scene(key), request.vis_dir, request.max_views, dataset.eval_models)
