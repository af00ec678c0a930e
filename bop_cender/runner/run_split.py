"""``run``: a method over a dataset split, its steps in order: the checks, the shards kept, the scenes, the merge.

Scenes are independent: each is estimated on its own and written as a shard (:mod:`~bop_cender.runner.shards`) as
it finishes, so a run killed at any point is resumed with ``resume`` at the first scene it had not finished; when
every scene has an outcome, they are merged into the BOP results CSV and its sidecar
(:mod:`~bop_cender.runner.merge`).
"""

from __future__ import annotations

import shutil
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from bop_cender.data.types import Dataset
from bop_cender.errors import ConfigError, ResultsWarning, RunError
from bop_cender.runner.build import curvature_threshold, open_run_dataset, read_weights
from bop_cender.runner.merge import RunSummary, merge
from bop_cender.runner.pool import execute_scenes
from bop_cender.runner.request import (
    RunRequest,
    check_meshes,
    check_request,
    check_targets,
    check_views,
    loadable_scenes,
    resolve_weights,
    uses_network,
)
from bop_cender.runner.shards import (
    SceneOutcome,
    make_dirs,
    other_settings_shards,
    remove_empty,
    resumable_outcomes,
    shard_path,
    work_dir,
    write_shard,
)

if TYPE_CHECKING:  # the network code loads only where a run uses a network
    from bop_cender.net.weights import NetWeights


def run(
    request: RunRequest,
    dataset: Dataset | None = None,
    progress: Callable[[int, int, str], None] | None = None,
) -> RunSummary:
    """Run the method over the split and write ``request.out`` (BOP CSV) and its sidecar.

    Args:
        request: see :class:`~bop_cender.runner.request.RunRequest`.
        dataset: the already opened dataset (None: opened from the request).
        progress: called with (scenes done, scenes, last scene key) as scenes finish.

    Raises:
        ConfigError: bad request (output name, workers, limit).
        BopCenderError: the data cannot be opened.
    """
    start = time.perf_counter()
    check_request(request)
    request = resolve_weights(request)
    dataset = dataset or open_run_dataset(request)
    # the weights read once, here: a bad file fails before any scene; the threshold, the fingerprint and the method
    # are made from what was read
    weights = read_weights(request, dataset) if uses_network(request.heatmaps) else None
    threshold = curvature_threshold(request, weights)
    check_meshes(dataset)  # a bad mesh fails here too
    keys = list(dataset.scene_keys)[: request.limit_scenes] if request.limit_scenes else list(dataset.scene_keys)
    if not keys:
        raise ConfigError(f"the split {request.split!r} of {dataset.root} has no scenes", field="--split")
    scenes = loadable_scenes(dataset, keys, progress is not None)
    check_views(request, keys, scenes)
    check_targets(dataset, scenes)
    work = work_dir(request.out)
    fingerprint = request.fingerprint(weights)
    if work.exists() and not request.resume:
        shutil.rmtree(work)
    created = make_dirs(work)
    try:
        outcomes, resumed = _run_scenes(request, dataset, keys, work, fingerprint, progress, weights)
    except BaseException:
        if not any(work.iterdir()):
            remove_empty(created)  # nothing done: leave nothing behind, --out's new folders included
        raise
    failed = {k: o.error for k, o in outcomes.items() if o.error is not None}
    if len(failed) == len(keys):  # nothing to write: no results file, no sidecar, no shards to resume from
        shutil.rmtree(work, ignore_errors=True)
        remove_empty(created)
        raise RunError(
            f"every scene failed ({len(keys)}); nothing was written",
            file=request.out,
            problems=[f"scene {k}: {e}" for k, e in list(failed.items())[:10]]
            + ([f"... and {len(failed) - 10} more"] if len(failed) > 10 else []),
        )
    return merge(request, dataset, keys, outcomes, resumed, work, start, threshold)


def _run_scenes(
    request: RunRequest,
    dataset: Dataset,
    keys: list[str],
    work: Path,
    fingerprint: str,
    progress: Callable[[int, int, str], None] | None,
    weights: NetWeights | None,
) -> tuple[dict[str, SceneOutcome], int]:
    """Shards of the same settings kept, the other scenes estimated (with the ``weights`` already read) and written as
    they finish; the outcomes by scene key and how many were kept."""
    targets = {i for i, m in dataset.models.items() if m.is_target}
    outcomes = resumable_outcomes(work, keys, fingerprint, targets)
    resumed = len(outcomes)
    redone = other_settings_shards(work, [k for k in keys if k not in outcomes], fingerprint)
    if redone:  # said up front: a changed setting (or an older bop-cender) must not look like a slow resume
        warnings.warn(f"{work}: {redone} shards made with other settings, another version of bop-cender or for"
                      " other data are estimated again", ResultsWarning, stacklevel=2)  # fmt: skip
    todo = [k for k in keys if k not in outcomes]
    done = resumed
    if progress is not None:
        progress(done, len(keys), "")
    for outcome in execute_scenes(request, dataset, todo, weights):
        write_shard(shard_path(work, outcome.scene_key), outcome, fingerprint)
        outcomes[outcome.scene_key] = outcome
        done += 1
        if progress is not None:
            progress(done, len(keys), outcome.scene_key)
    return outcomes, resumed
