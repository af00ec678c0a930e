"""Run a method over a dataset split: per-scene shards, resume, worker processes, one BOP CSV at the end.

Scenes are independent (docs/design.md, "The data flow"): each is estimated on its own and written as a small JSON
shard into a work folder next to the output (``<out>.parts/``), atomically, so a run killed at any point leaves only whole shards. ``resume`` keeps the
shards made with the same settings and runs the rest; when every scene has a shard, they are merged into the BOP
results CSV (atomically) with its run sidecar, and the work folder is removed. Worker processes (``workers > 1``)
each open the dataset and build the method themselves, with one torch thread each; every random draw is seeded per
scene, so the rows are the same whatever the number of workers (only the measured ``time`` column differs, and
``deterministic_time`` writes BOP's ``-1`` there).

One module per job, each importing only those listed before it:

- :mod:`~bop_cender.runner.request`: :class:`RunRequest` and every check before the first scene;
- :mod:`~bop_cender.runner.build`: the dataset, the network weights and the method of a request;
- :mod:`~bop_cender.runner.shards`: the per-scene shards and what ``--resume`` keeps;
- :mod:`~bop_cender.runner.worker`: one scene estimated, and what a worker builds once for all its scenes;
- :mod:`~bop_cender.runner.pool`: the scenes estimated in this process or in worker processes (the executor's seam);
- :mod:`~bop_cender.runner.ray_executor`: the scenes estimated by Ray actors on a cluster (``--executor ray``);
- :mod:`~bop_cender.runner.merge`: the BOP CSV and its sidecar;
- :mod:`~bop_cender.runner.run_split`: :func:`run`, the steps in order.
"""

from bop_cender.runner.build import build_method, method_for, net_predictor, open_run_dataset
from bop_cender.runner.merge import RunSummary
from bop_cender.runner.request import HEATMAP_SOURCES, RunRequest, resolve_weights, results_dataset_name, uses_network
from bop_cender.runner.run_split import run
from bop_cender.runner.shards import SceneOutcome, read_shard, shard_path, work_dir, write_shard
from bop_cender.runner.worker import estimate_scene

__all__ = [
    "HEATMAP_SOURCES",
    "RunRequest",
    "RunSummary",
    "SceneOutcome",
    "build_method",
    "estimate_scene",
    "method_for",
    "net_predictor",
    "open_run_dataset",
    "read_shard",
    "resolve_weights",
    "results_dataset_name",
    "run",
    "shard_path",
    "uses_network",
    "work_dir",
    "write_shard",
]
