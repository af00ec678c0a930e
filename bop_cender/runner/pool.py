"""Where the scenes are estimated: in the run's process (with ``--threads`` for the compiled loops) or in a pool of
worker processes (``--workers``), one outcome per scene as scenes finish.

Worker processes are started with ``spawn``; each opens the dataset and builds the method itself (once, in its
initializer), with one torch thread. Every random draw is seeded per scene, so the rows are the same whatever the
number of workers or threads.
"""

from __future__ import annotations

import os
import sys
import warnings
from collections.abc import Iterator, Mapping
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, replace
from multiprocessing import get_context
from pathlib import Path
from typing import TYPE_CHECKING

from bop_cender.data.types import Dataset, ObjectModel, Scene
from bop_cender.errors import BopCenderError, DatasetWarning
from bop_cender.method import CenDerNet
from bop_cender.runner.build import build_method, open_run_dataset
from bop_cender.runner.request import RunRequest
from bop_cender.runner.shards import SceneOutcome, shard_path

if TYPE_CHECKING:  # the network code loads only where a run uses a network
    from bop_cender.net.weights import NetWeights


def execute_scenes(
    request: RunRequest, dataset: Dataset, keys: list[str], weights: NetWeights | None = None
) -> Iterator[SceneOutcome]:
    """Yield a :class:`SceneOutcome` per key as scenes finish (in order with one worker).

    ``weights``: the request's network weights, already read by this process
    (:func:`~bop_cender.runner.build.read_weights`; None: read here where a network is used); each worker process
    reads them once itself."""
    if not keys:
        return
    if request.workers == 1 or len(keys) == 1:
        # One torch thread here too: the method's tensors are small (Nelder-Mead steps of a few poses, chunks
        # of a few hundred canvases), where torch's OpenMP threads cost more than they give, and on a busy
        # machine they wait for each other a scheduler slice per operation: a 9-part DIMO scene took 28 s
        # with 1 thread and 291 s with 2 on the shared 2-core machine (results/bench/run_*). The render
        # search's candidate chunks still use the cores (cost_threads).
        import torch

        from bop_cender.render.numba_loops import compiled_threads

        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            method = build_method(request, dataset, max(1, min(2, os.cpu_count() or 1)), weights)
            with compiled_threads(request.threads):
                for key in keys:
                    yield estimate_scene(
                        method, dataset.scene(key), request.vis_dir, request.max_views, dataset.eval_models
                    )
        finally:
            torch.set_num_threads(threads)
        return
    build_method(request, dataset, weights=weights)  # a bad request fails here, once, before any process starts
    ctx = get_context("spawn")
    workers = min(request.workers, len(keys))
    with ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_worker, initargs=(request,)) as pool:
        futures = [pool.submit(_worker_scene, key) for key in keys]
        for future in as_completed(futures):
            yield future.result()


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
            Path(vis_dir) / shard_path(Path(), scene.key).with_suffix(".png").name,
            judge_models=eval_models or None,
        )
    return SceneOutcome(scene.key, output.estimate)


@dataclass
class WorkerState:
    """What a worker process builds once (in its initializer) and uses for each of its scenes."""

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


_STATE: list[WorkerState] = []  # one entry in a worker process, set by its initializer


def _init_worker(request: RunRequest) -> None:
    """Worker process start: one torch thread (the processes share the cores), the dataset, the method."""
    import torch

    _exit_with_parent()
    torch.set_num_threads(1)
    # the run's process has said every dataset warning already (it opens the data, reads every mesh and scene first):
    # each worker repeating them, in Python's raw format, said each one N + 1 times
    warnings.simplefilter("ignore", DatasetWarning)
    _STATE[:] = [WorkerState.build(request)]


def _exit_with_parent() -> None:
    """On Linux, have the kernel stop this worker when the run's process dies (a killed run leaves no
    orphan computing a scene nobody will collect)."""
    if sys.platform.startswith("linux"):
        import contextlib
        import ctypes
        import signal

        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, int(signal.SIGTERM))  # PR_SET_PDEATHSIG


def _worker_scene(key: str) -> SceneOutcome:
    """One scene in a worker process."""
    return _STATE[0].estimate(key)
