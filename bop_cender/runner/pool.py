"""Where the scenes are estimated: in the run's process (with ``--threads`` for the compiled loops), in a pool of
worker processes (``--workers``) or on a Ray cluster (``--executor ray``, :mod:`~bop_cender.runner.ray_executor`),
one outcome per scene as scenes finish. :func:`execute_scenes` is the one place the executor is chosen.

Worker processes are started with ``spawn``; each opens the dataset and builds the method itself (once, in its
initializer), with one torch thread. Every random draw is seeded per scene, so the rows are the same whatever the
number of workers or threads.
"""

from __future__ import annotations

import os
import sys
import warnings
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from typing import TYPE_CHECKING

from bop_cender.data.types import Dataset
from bop_cender.errors import DatasetWarning
from bop_cender.runner.build import build_method
from bop_cender.runner.request import RunRequest
from bop_cender.runner.shards import SceneOutcome
from bop_cender.runner.worker import WorkerState, estimate_scene

if TYPE_CHECKING:  # the network code loads only where a run uses a network
    from bop_cender.net.weights import NetWeights


def execute_scenes(
    request: RunRequest, dataset: Dataset, keys: list[str], weights: NetWeights | None = None
) -> Iterator[SceneOutcome]:
    """Yield a :class:`SceneOutcome` per key as scenes finish (in order with one worker), on the request's executor.

    ``weights``: the request's network weights, already read by this process
    (:func:`~bop_cender.runner.build.read_weights`; None: read here where a network is used); each worker process
    reads them once itself, as each Ray actor does on its node."""
    if not keys:
        return
    workers = min(request.workers or 1, len(keys))
    if request.executor == "ray" or workers > 1:
        build_method(request, dataset, weights=weights)  # a bad request fails here, once, before any worker starts
    if request.executor == "ray":
        from bop_cender.runner.ray_executor import ray_scenes

        yield from ray_scenes(request, keys)
        return
    if workers == 1:
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
    ctx = get_context("spawn")
    with ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_worker, initargs=(request,)) as pool:
        futures = [pool.submit(_worker_scene, key) for key in keys]
        for future in as_completed(futures):
            yield future.result()


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
