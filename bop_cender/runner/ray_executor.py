"""``run --executor ray``: the scenes estimated by Ray actors on a cluster, their outcomes sent back to the run's process.

Each actor (:class:`SceneWorker`, one CPU, one torch thread) opens the dataset and builds the method once, from the
request, and then estimates scene after scene (:class:`~bop_cender.runner.worker.WorkerState`, as a worker process of
``--workers`` does). Neither the data nor the weights travel: each node opens the request's data path and reads the
weights file itself (the shipped weights: those of its own install), so every node needs the data and a ``--weights``
file at the same paths (a copy will do; the actors' arguments stay small, so that Ray can restart an actor from them),
and an actor that cannot open them stops the run before any scene with an error naming its node and the path. What comes back is each
scene's :class:`~bop_cender.runner.shards.SceneOutcome` (and its ``--vis`` figure as PNG bytes): the run's process
writes the shards, the figures and the results, so the nodes share no disk.

A scene whose method raises is already an outcome with its error. A scene whose actor dies (killed, out of memory,
its node lost) is run again by Ray on the restarted actor (:data:`~bop_cender.cluster.TASK_RETRIES` times); after
that it is a failed scene like any other (the sidecar's ``failed_scenes``, redone by ``--resume``), never a failed
run. Every random draw is seeded per scene, so the rows are those of ``--workers 1``.
"""

from __future__ import annotations

import shutil
import tempfile
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

from bop_cender.cluster import (
    WorkerHello,
    actor_count,
    as_completed,
    check_started,
    first_line,
    node_name,
    ray_session,
    start_actors,
    stop_actors,
)
from bop_cender.data.bop_io import atomic_path
from bop_cender.errors import BopCenderError, ConfigError, DatasetError, DatasetWarning
from bop_cender.runner.build import build_method, open_run_dataset
from bop_cender.runner.request import RunRequest, uses_network
from bop_cender.runner.shards import SceneOutcome
from bop_cender.runner.worker import WorkerState, figure_name


@dataclass(frozen=True)
class RemoteOutcome:
    """One scene's outcome as an actor returns it, with its ``--vis`` figure (PNG bytes; None: no figure)."""

    outcome: SceneOutcome
    figure: bytes | None = None


class SceneWorker:
    """A Ray actor's state: the dataset and the method of the request, built once, then one scene per call.

    Built on the actor's node from the node's own files (the data, the weights); what cannot be read there is kept
    as :attr:`problem` (said by :meth:`hello`, and as the error of any scene asked for), not raised: a constructor
    that raises leaves Ray's own error, which does not say that the node lacks a file."""

    def __init__(self, request: RunRequest) -> None:
        import torch

        torch.set_num_threads(1)  # one CPU per actor (its Ray resource)
        warnings.simplefilter("ignore", DatasetWarning)  # the run's process has said them
        self.node = node_name()
        self.figures = Path(tempfile.mkdtemp(prefix="bop-cender-vis-")) if request.vis_dir is not None else None
        self.state: WorkerState | None = None
        self.problem: str | None = None
        request = replace(request, vis_dir=self.figures)
        try:
            dataset = open_run_dataset(request)
        except (BopCenderError, OSError) as e:
            where = f"the data at {request.data_root}" if request.data_root else "the embedded demo data"
            self.problem = (
                f"node {self.node} cannot open {where}: {e}; every node of the cluster needs the data at the same"
                " path (a copy will do): docs/cluster.md"
            )
            return
        try:
            self.state = WorkerState(request, dataset, build_method(request, dataset))
        except (BopCenderError, OSError) as e:
            self.problem = (
                f"node {self.node} cannot build the method (weights {request.weights}): {e}; every node needs the"
                " weights file at the same path: docs/cluster.md"
            )

    def hello(self) -> WorkerHello:
        """The node and the problem, if any: asked once by the run's process before any scene."""
        return WorkerHello.here(self.problem)

    def estimate(self, key: str) -> RemoteOutcome:
        """Scene ``key``: its outcome (an error of the scene is the outcome's) and its figure, removed from this
        node once read."""
        if self.state is None:  # an actor restarted on a node without the data
            return RemoteOutcome(SceneOutcome(key, None, f"DatasetError: {self.problem}"))
        outcome = self.state.estimate(key)
        figure = None
        if self.figures is not None:
            path = self.figures / figure_name(key)
            if path.is_file():
                figure = path.read_bytes()
                path.unlink()
        return RemoteOutcome(outcome, figure)

    def __del__(self) -> None:
        if getattr(self, "figures", None) is not None:
            shutil.rmtree(self.figures, ignore_errors=True)


def ray_scenes(request: RunRequest, keys: list[str]) -> Iterator[SceneOutcome]:
    """Yield a :class:`SceneOutcome` per key as the actors finish them, each scene's figure written first (``--vis``).

    The request has been checked here already (:func:`~bop_cender.runner.pool.execute_scenes` builds its method once
    before any worker starts); each actor reads its node's data and weights once.

    Raises:
        ConfigError: Ray not installed, the cluster cannot be reached, more workers than its CPUs, or an actor
            could not start (bop-cender not installed on its node, or no CPU free for it).
        DatasetError: a node cannot open the data or read the weights (the message says which).
    """
    request = _for_the_nodes(request)
    with ray_session(request.address):
        actors = start_actors(SceneWorker, actor_count(request.workers, len(keys)), request)
        try:
            for hello in check_started(actors):
                if hello.problem is not None:
                    raise DatasetError(hello.problem)
            for key, remote, error in as_completed(actors, keys, lambda actor, key: actor.estimate.remote(key)):
                if error is not None:
                    yield SceneOutcome(key, None, f"the Ray worker running it failed: {first_line(error)}")
                    continue
                if remote.figure is not None and request.vis_dir is not None:
                    with atomic_path(Path(request.vis_dir) / figure_name(key)) as tmp:
                        tmp.write_bytes(remote.figure)
                yield remote.outcome
        finally:
            stop_actors(actors)


def _for_the_nodes(request: RunRequest) -> RunRequest:
    """The request as the actors read it: absolute paths (an actor's working folder is not this process's), and no
    weights path where they are the shipped ones (each node reads those of its own install, wherever it is)."""
    if request.data_root is not None:
        request = replace(request, data_root=str(Path(request.data_root).resolve()))
    if request.weights is not None:
        request = replace(request, weights=str(Path(request.weights).resolve()))
        if uses_network(request.heatmaps) and Path(request.weights) == _shipped(request.dataset):
            request = replace(request, weights=None)  # resolved again on each node (resolve_weights)
    return request


def _shipped(dataset: str) -> Path | None:
    """Where this install's shipped weights for ``dataset`` are (None: none shipped)."""
    from bop_cender.net.weights import shipped_weights_path

    try:
        return shipped_weights_path(dataset).resolve()
    except ConfigError:
        return None
