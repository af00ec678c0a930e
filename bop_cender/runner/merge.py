"""The end of a run: every scene's outcome merged into the BOP results CSV and its run sidecar (JSON).

The CSV holds the rows of the scenes that did not fail, in the split's scene order; the sidecar records what made
them (data, settings, heatmap source, curvature threshold) and names the failed scenes, whose targets ``score``
counts as misses. Both are written atomically; the work folder of shards goes once no scene failed (else its shards
let ``--resume`` redo only the failed scenes).
"""

from __future__ import annotations

import shutil
import time
from dataclasses import dataclass, replace
from pathlib import Path

from bop_cender.data.types import Dataset
from bop_cender.results.bop_csv import scene_estimates_to_rows, write_bop_results
from bop_cender.results.files import write_run_sidecar
from bop_cender.runner.request import RunRequest
from bop_cender.runner.shards import SceneOutcome


@dataclass(frozen=True)
class RunSummary:
    """What a run did: output files, scene counts, failures and time per stage."""

    out: Path
    sidecar: Path
    scenes: int
    resumed: int
    rows: int
    estimates: int
    failed: dict[str, str]
    empty: list[str]
    stage_seconds: dict[str, float]
    wall_seconds: float
    curvature_threshold: float  # where stage 3 binarised the curvature
    curvature_threshold_source: str  # which setting gave it


def merge(
    request: RunRequest,
    dataset: Dataset,
    keys: list[str],
    outcomes: dict[str, SceneOutcome],
    resumed: int,
    work: Path,
    start: float,
    threshold: tuple[float, str],
) -> RunSummary:
    """All shards into one BOP CSV and its sidecar (atomic writes), then the work folder goes.

    Args:
        keys: the run's scenes, in the order of their rows; ``outcomes`` holds one for each.
        resumed: how many outcomes came from the shards of an earlier run.
        work: the work folder of shards (removed when no scene failed).
        start: ``time.perf_counter()`` at the run's start (for the summary's wall time).
        threshold: where stage 3 binarised the curvature and which setting said so (for the sidecar).
    """
    rows = []
    stage_seconds: dict[str, float] = {}
    scene_seconds: dict[str, dict[str, float]] = {}
    failed, empty = {}, []
    n_estimates = 0
    for key in keys:
        outcome = outcomes[key]
        if outcome.error is not None:
            failed[key] = outcome.error
            continue
        est = outcome.estimate
        assert est is not None
        if not est.objects:
            empty.append(key)
        n_estimates += len(est.objects)
        for stage, seconds in est.timings.items():
            stage_seconds[stage] = stage_seconds.get(stage, 0.0) + seconds
        scene_seconds[key] = {stage: round(seconds, 3) for stage, seconds in est.timings.items()}
        scene = dataset.scene(key)
        image_time = -1.0 if request.deterministic_time else est.time_s / max(1, len(scene.evaluated_views))
        rows.extend(scene_estimates_to_rows(scene, replace(est, time_s=image_time)))
    write_bop_results(request.out, rows)
    sidecar = write_run_sidecar(
        request.out,
        dataset.root,
        request.dataset,
        request.split,
        {
            "n_views": request.n_views,
            "scenes": len(keys),
            "limit_scenes": request.limit_scenes,
            # a partial run names its scenes, so that `score` counts only their targets
            **({"scene_keys": keys} if request.limit_scenes and len(keys) < len(dataset.scene_keys) else {}),
        },
        request.seed,
        extra={
            "method": "cendernet",
            "task": request.task,
            "protocol": request.protocol,  # `score FILE.csv` scores it under this protocol without a flag
            "heatmaps": request.heatmaps,
            "weights": request.weights,
            "model_type": request.model_type,
            "config": request.config.as_dict(),
            "devices": {"heatmaps": request.device, "poses": request.pose_device},
            # where this run's scenes were estimated (not in the shards' fingerprint: a resume may use another)
            "executor": request.executor,
            "curvature_threshold": {"value": threshold[0], "from": threshold[1]},
            "time": "per image: the scene's wall time divided by its views" if not request.deterministic_time else -1,
            # scenes with no rows because they failed (their targets count as misses); absent when none did
            **({"failed_scenes": failed} if failed else {}),
            # seconds per stage, in all and per scene (`bop-cender report` shows them); left out where the run was
            # asked for reproducible files (--deterministic-time), as the rows' times are
            **(
                {}
                if request.deterministic_time
                else {
                    "timings": {
                        "stages": {stage: round(seconds, 3) for stage, seconds in stage_seconds.items()},
                        "wall": round(time.perf_counter() - start, 3),
                        "scenes": scene_seconds,
                    }
                }
            ),
            # where the run wrote its per-scene figures (`bop-cender report` shows them)
            **({"vis_dir": str(request.vis_dir.resolve())} if request.vis_dir is not None else {}),
        },
    )
    if not failed:
        shutil.rmtree(work, ignore_errors=True)
    # else the shards stay: `--resume` keeps the scenes done and redoes only the failed ones (read_shard)
    return RunSummary(
        out=request.out,
        sidecar=sidecar,
        scenes=len(keys),
        resumed=resumed,
        rows=len(rows),
        estimates=n_estimates,
        failed=failed,
        empty=empty,
        stage_seconds=stage_seconds,
        wall_seconds=time.perf_counter() - start,
        curvature_threshold=threshold[0],
        curvature_threshold_source=threshold[1],
    )
