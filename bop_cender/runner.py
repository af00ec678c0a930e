"""Run a method over a dataset split: per-scene shards, resume, worker processes, one BOP CSV at the end.

Scenes are independent (design.md, "Scale"): each is estimated on its own and written as a small JSON
shard into a work folder next to the output (``<out>.parts/``), atomically, so a run killed at any point
leaves only whole shards. ``resume`` keeps the shards made with the same settings and runs the rest;
when every scene has a shard, they are merged into the BOP results CSV (atomically) with its run
sidecar, and the work folder is removed. Worker processes (``workers > 1``) each open the dataset and
build the method themselves, with one torch thread each; every random draw is seeded per scene, so the
rows are the same whatever the number of workers (only the measured ``time`` column differs, and
``deterministic_time`` writes BOP's ``-1`` there).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import sys
import time
import warnings
from collections.abc import Callable, Collection, Mapping
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, replace
from multiprocessing import get_context
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bop_cender.data.bop_io import atomic_path, check_output_dir, check_output_file
from bop_cender.data.types import Dataset, ObjectModel, Scene
from bop_cender.errors import BopCenderError, ConfigError, DatasetWarning, RunError
from bop_cender.estimates import ObjectEstimate, SceneEstimate
from bop_cender.eval.toolkit_constants import TOOLKIT_TEST_WIDTHS
from bop_cender.meshes import MeshCache
from bop_cender.method import CenDerNet, CenDerNetConfig, network_curvature_choice
from bop_cender.progress import progress_bar
from bop_cender.results.bop_csv import scene_estimates_to_rows, write_bop_results
from bop_cender.results.files import write_run_sidecar

if TYPE_CHECKING:  # the network code loads only where a run uses a network
    from bop_cender.net.weights import NetWeights

SHARD_FORMAT = "bop-cender-shard"
HEATMAP_SOURCES = ("oracle", "net", "oracle-centers", "oracle-curvature")
"""Heatmap sources of ``run``: the oracle, the network, or the two mixed (ablations): ``oracle-centers`` takes
the centres from the oracle and the curvature from the network, ``oracle-curvature`` the reverse."""
SHARD_VERSION = 1


@dataclass(frozen=True)
class RunRequest:
    """What to run: the data, the heatmap source, the method's settings and where to write.

    Attributes:
        dataset, data_root, split, n_views, model_type: the data (as ``open_dataset`` takes them).
        out: the BOP results CSV to write.
        heatmaps: ``oracle`` (GT heatmaps rendered from the annotations), ``net``, or one head of each
            (:data:`HEATMAP_SOURCES`: ``oracle-centers``, ``oracle-curvature``).
        weights: network weights (every source but ``oracle``).
        seed: seed of the view grouping and of the method's random candidates.
        config: the method's settings (None: :meth:`CenDerNetConfig.for_dataset` of ``dataset``, as ``run``
            makes them: T-LESS / BOP targets and stage 3 differ from DIMO's).
        workers: processes; scenes are spread over them.
        limit_scenes: only the first K scenes of the split (None: all).
        resume: keep the shards of an earlier, interrupted run with the same settings.
        deterministic_time: write ``-1`` as every row's time (reproducible files, for tests).
        device: torch device of the heatmaps.
        pose_device: torch device of stage 3 (renders and costs); the CPU by default (see
            :class:`~bop_cender.method.CenDerNet`: on CUDA its small batches are launch-bound).
        vis_dir: write a figure per scene there (:mod:`bop_cender.report.scene_figure`); None: no figures.
        max_views: estimate from the first K views of each scene only (an ablation); the rows are
            still written for every view, so the scores compare with a run on all views.
        threads: threads of the compiled CPU loops (renderer, stage 3's costs) when one process runs the scenes;
            the same rows whatever the count (each canvas is summed by one thread, torch keeps one). Not with
            ``workers`` > 1.
    """

    dataset: str
    data_root: str | None
    split: str
    out: Path
    n_views: int | None = None
    model_type: str | None = None
    heatmaps: str = "oracle"
    weights: str | None = None
    seed: int = 0
    config: CenDerNetConfig = None  # type: ignore[assignment]  # set in __post_init__
    workers: int = 1
    limit_scenes: int | None = None
    resume: bool = False
    deterministic_time: bool = False
    device: str = "cpu"
    pose_device: str = "cpu"
    vis_dir: Path | None = None
    max_views: int | None = None
    threads: int = 1

    def __post_init__(self) -> None:
        if self.config is None:
            object.__setattr__(self, "config", CenDerNetConfig.for_dataset(self.dataset))

    def fingerprint(self) -> str:
        """What a shard depends on: data, heatmap source, seed and config (not out, workers or resume)."""
        key = {
            "dataset": self.dataset,
            "data_root": str(Path(self.data_root).resolve()) if self.data_root else None,
            "split": self.split,
            "n_views": self.n_views,
            "model_type": self.model_type,
            "heatmaps": self.heatmaps,
            "weights": _file_digest(self.weights),
            "seed": self.seed,
            "config": self.config.as_dict(),
            "max_views": self.max_views,
        }
        return hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _file_digest(path: str | None) -> str | None:
    """sha256 of a weights file (retrained weights under the same name invalidate the shards); the path if unreadable."""
    if path is None:
        return None
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return str(path)


@dataclass(frozen=True)
class SceneOutcome:
    """One scene's result as the runner keeps it (what a shard holds)."""

    scene_key: str
    estimate: SceneEstimate | None
    error: str | None = None


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


def open_run_dataset(request: RunRequest) -> Dataset:
    from bop_cender.data.registry import DatasetRequest
    from bop_cender.datasets import open_with_demo

    data = DatasetRequest(
        request.dataset, request.data_root, request.split, request.n_views, request.seed, request.model_type
    )
    return open_with_demo(data)  # no data root: the embedded demo, silently


def build_method(request: RunRequest, dataset: Dataset, cost_threads: int = 1) -> CenDerNet:
    """The method for a request: oracle heatmaps, the network (given or shipped weights), or one head of each."""
    from bop_cender.net.mixed import MixedPredictor
    from bop_cender.net.oracle import OraclePredictor

    _check_source(request.heatmaps)
    meshes = MeshCache(dataset.models)
    if request.heatmaps == "oracle":
        predictor = OraclePredictor(dataset.models, meshes, request.config.targets, device=request.device)
    else:
        predictor = net = net_predictor(request, dataset)
        if request.heatmaps != "net":  # one head of each; the oracle's centre channels follow the network's
            oracle = OraclePredictor(
                dataset.models, meshes, request.config.targets, net.channel_obj_ids, device=request.device
            )
            oracle_centers = request.heatmaps == "oracle-centers"
            predictor = MixedPredictor(oracle, net) if oracle_centers else MixedPredictor(net, oracle)
    return CenDerNet(
        dataset.models, request.config, predictor, meshes, cost_threads=cost_threads, pose_device=request.pose_device
    )


def uses_network(heatmaps: str) -> bool:
    """Whether the heatmap source ``heatmaps`` (one of :data:`HEATMAP_SOURCES`) runs the network."""
    return heatmaps in HEATMAP_SOURCES and heatmaps != "oracle"


def _check_source(heatmaps: str) -> None:
    if heatmaps not in HEATMAP_SOURCES:
        raise ConfigError(
            f"unknown heatmap source {heatmaps!r}; expected one of {', '.join(HEATMAP_SOURCES)}", field="--heatmaps"
        )


def resolve_weights(request: RunRequest) -> RunRequest:
    """``request`` with ``weights`` set to a file: the given one, or the shipped weights of the dataset kind."""
    if not uses_network(request.heatmaps) or request.weights is not None:
        return request
    from bop_cender.net.weights import shipped_weights_path

    return replace(request, weights=str(shipped_weights_path("dimo" if request.dataset == "dimo" else "tless")))


def method_for(request: RunRequest) -> tuple[RunRequest, Dataset, CenDerNet]:
    """The request with its weights resolved, its dataset and its method: what a script that runs scenes through the
    method by hand needs (``scripts/centre_placement.py``, ``scripts/centre_families.py``)."""
    request = resolve_weights(request)
    dataset = open_run_dataset(request)
    return request, dataset, build_method(request, dataset)


def net_predictor(request: RunRequest, dataset: Dataset):
    """The network predictor of ``request`` (weights resolved), checked against the dataset and the config.

    Raises:
        ConfigError: weights for another dataset kind, center channels that miss a target object of the
            dataset, or targets (curvature scale) other than the config's.
    """
    from bop_cender.net.predictor import NetPredictor
    from bop_cender.net.weights import check_covers_targets, load_weights

    weights = load_weights(resolve_weights(request).weights, dataset=request.dataset)
    check_covers_targets(weights, dataset.models)
    if weights.targets.curvature_scale != request.config.targets.curvature_scale:
        raise ConfigError(
            f"the weights were trained on curvature / {weights.targets.curvature_scale:g}; this run's config says"
            f" / {request.config.targets.curvature_scale:g} (--set targets.curvature_scale=...)",
            file=weights.path,
        )
    return NetPredictor(
        weights,
        device=request.device,
        known_object_ids=request.config.known_object_ids,
        curvature_threshold=_network_threshold(request, weights)[0],
    )


def _network_threshold(request: RunRequest, weights: NetWeights) -> tuple[float | None, str]:
    """:func:`~bop_cender.method.network_curvature_choice` for a run on ``request.split`` with ``weights``
    (:class:`~bop_cender.net.weights.NetWeights`): the split's own calibration where the weights carry one."""
    return network_curvature_choice(request.config, *weights.curvature_threshold_for(request.split))


def run(
    request: RunRequest,
    dataset: Dataset | None = None,
    progress: Callable[[int, int, str], None] | None = None,
) -> RunSummary:
    """Run the method over the split and write ``request.out`` (BOP CSV) and its sidecar.

    Args:
        request: see :class:`RunRequest`.
        dataset: the already opened dataset (None: opened from the request).
        progress: called with (scenes done, scenes, last scene key) as scenes finish.

    Raises:
        ConfigError: bad request (output name, workers, limit).
        BopCenderError: the data cannot be opened.
    """
    start = time.perf_counter()
    _check_request(request)
    request = resolve_weights(request)
    dataset = dataset or open_run_dataset(request)
    threshold = _curvature_threshold(request, dataset)  # bad weights fail here, once, before any scene
    _check_meshes(dataset)  # and a bad mesh
    keys = list(dataset.scene_keys)[: request.limit_scenes] if request.limit_scenes else list(dataset.scene_keys)
    if not keys:
        raise ConfigError(f"the split {request.split!r} of {dataset.root} has no scenes", field="--split")
    scenes = _loadable_scenes(dataset, keys, progress is not None)
    _check_views(request, keys, scenes)
    _check_targets(dataset, scenes)
    work = work_dir(request.out)
    fingerprint = request.fingerprint()
    if work.exists() and not request.resume:
        shutil.rmtree(work)
    created = _make_dirs(work)
    try:
        outcomes, resumed = _run_scenes(request, dataset, keys, work, fingerprint, progress)
    except BaseException:
        if not any(work.iterdir()):
            _remove_empty(created)  # nothing done: leave nothing behind, --out's new folders included
        raise
    failed = {k: o.error for k, o in outcomes.items() if o.error is not None}
    if len(failed) == len(keys):  # nothing to write: no results file, no sidecar, no shards to resume from
        shutil.rmtree(work, ignore_errors=True)
        _remove_empty(created)
        raise RunError(
            f"every scene failed ({len(keys)}); nothing was written",
            file=request.out,
            problems=[f"scene {k}: {e}" for k, e in list(failed.items())[:10]]
            + ([f"... and {len(failed) - 10} more"] if len(failed) > 10 else []),
        )
    return _merge(request, dataset, keys, outcomes, resumed, work, start, threshold)


def _loadable_scenes(dataset: Dataset, keys: list[str], progress: bool) -> list[Scene]:
    """The scenes of ``keys`` that load (kept in ``dataset``'s cache for a run in this process), for the checks before
    the first scene; a scene that does not is left to fail on its own, with its error. A bar on stderr for a large
    split (1,200 synthetic T-LESS scenes: 1.3 s)."""
    scenes = []
    bar = progress_bar(keys, desc="reading scenes", unit="scene", disable=not progress or len(keys) < 200, leave=False)
    for key in bar:
        try:
            scenes.append(dataset.scene(key))
        except BopCenderError:
            continue
    return scenes


def _check_views(request: RunRequest, keys: list[str], scenes: list[Scene]) -> None:
    """Scenes of fewer views than ``centers.min_views`` (after ``--max-views``) can have no 3D centre, so no object:
    refused when every scene is one (a run of nothing but empty rows, exit 0, ended in a ``score`` that had nothing
    to score), a warning naming them otherwise. BOP-layout images without a camera pose are scenes of one view each,
    and a last group of a scene may hold fewer views than ``--n-views``. ``scenes``: those of ``keys`` that load."""
    centers = request.config.centers
    need = centers.min_views if request.config.known_counts else max(centers.min_views, centers.min_views_unknown_count)
    short: dict[str, int] = {}
    for scene in scenes:
        views = len(scene.views) if request.max_views is None else min(len(scene.views), request.max_views)
        if views < need:
            short[scene.key] = views
    if not short:
        return
    listed = ", ".join(f"{k} ({v})" for k, v in list(short.items())[:5]) + (" ..." if len(short) > 5 else "")
    if request.dataset == "dimo":  # a DIMO scene's views are its images of the selected viewpoints
        advice, field = "DIMO reads viewpoints 0, 2, 4, ... of a scene: its scenes need more images", "--split"
    else:
        advice, field = (
            "group more views per scene (--n-views), or give every image its camera pose (cam_R_w2c, cam_t_w2c in"
            " scene_camera.json)",
            "--n-views",
        )
    why = f"fewer views than the {need} a 3D centre is triangulated from (centers.min_views): {listed}; {advice}"
    if len(short) == len(keys):
        raise ConfigError(f"every scene has {why}", field=field)
    warnings.warn(f"{len(short)} of {len(keys)} scenes have {why}: no object can be found in them", DatasetWarning,
                  stacklevel=3)  # fmt: skip


def _check_targets(dataset: Dataset, scenes: list[Scene]) -> None:
    """The BOP targets file as ``score`` will judge it, before any scene (:func:`~bop_cender.eval.targets.
    targets_file_problems`: malformed, or asking for more instances than an image's ground truth has): a run on such a
    file did all its work and exited 0, and its ``score`` then refused it.

    Raises:
        ConfigError: the first problem (``bop-cender info`` lists them all).
    """
    from bop_cender.eval.targets import targets_file_problems

    problems = targets_file_problems(dataset, scenes)
    if problems:
        more = f" (and {len(problems) - 1} more: bop-cender info lists them)" if len(problems) > 1 else ""
        raise ConfigError(f"{problems[0]}{more}: score would refuse this split's targets")


def _check_meshes(dataset: Dataset) -> None:
    """Every model's mesh read and checked once, before any scene (:meth:`~bop_cender.meshes.MeshCache.arrays`: a
    mesh of another size than its ``models_info.json`` entry, a broken PLY): found by the first scene to use it, such
    a mesh failed every scene after its network pass, each with the same error."""
    meshes = MeshCache(dataset.models)
    for obj_id in dataset.models:
        meshes.arrays(obj_id)


def _make_dirs(folder: Path) -> list[Path]:
    """``mkdir -p folder``; returns the folders it created, outermost first (to remove them when nothing
    was written)."""
    created = [p for p in (*reversed(folder.parents), folder) if not p.exists()]
    folder.mkdir(parents=True, exist_ok=True)
    return created


def _remove_empty(created: list[Path]) -> None:
    """Remove the folders :func:`_make_dirs` created, innermost first, where they are still empty."""
    for folder in reversed(created):
        if not folder.exists():
            continue
        try:
            folder.rmdir()
        except OSError:  # not empty: another file landed there, and so in its parents
            return


def _run_scenes(request, dataset, keys, work, fingerprint, progress) -> tuple[dict[str, SceneOutcome], int]:
    """Shards of the same settings kept, the other scenes estimated and written as they finish."""
    outcomes: dict[str, SceneOutcome] = {}
    targets = {i for i, m in dataset.models.items() if m.is_target}
    for key in keys:
        shard = read_shard(shard_path(work, key), fingerprint, key, targets)
        if shard is not None:
            outcomes[key] = shard
    resumed = len(outcomes)
    todo = [k for k in keys if k not in outcomes]
    done = resumed
    if progress is not None:
        progress(done, len(keys), "")
    for outcome in _execute(request, dataset, todo):
        write_shard(shard_path(work, outcome.scene_key), outcome, fingerprint)
        outcomes[outcome.scene_key] = outcome
        done += 1
        if progress is not None:
            progress(done, len(keys), outcome.scene_key)
    return outcomes, resumed


def _curvature_threshold(request: RunRequest, dataset: Dataset) -> tuple[float, str]:
    """Where stage 3 binarises the curvature of ``request``'s heatmaps, and which setting says so (for the sidecar
    and the summary): a network's curvature at ``poses.network.t_b`` or the weights' calibration, else ``t_b``.
    Loads the network's weights (when one is used): a bad file fails here, before any scene."""
    if not uses_network(request.heatmaps):
        return request.config.poses.t_b, "poses.t_b"
    net = net_predictor(request, dataset)
    if request.heatmaps == "oracle-curvature":
        return request.config.poses.t_b, "poses.t_b"
    value, source = _network_threshold(request, net.weights)
    return (request.config.poses.t_b if value is None else value), source


def _merge(request, dataset, keys, outcomes, resumed, work, start, threshold: tuple[float, str]) -> RunSummary:
    """All shards into one BOP CSV and its sidecar (atomic writes), then the work folder goes."""
    rows = []
    stage_seconds: dict[str, float] = {}
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
        scene = dataset.scene(key)
        image_time = -1.0 if request.deterministic_time else est.time_s / len(scene.views)
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
            "heatmaps": request.heatmaps,
            "weights": request.weights,
            "model_type": request.model_type,
            "config": request.config.as_dict(),
            "devices": {"heatmaps": request.device, "poses": request.pose_device},
            "curvature_threshold": {"value": threshold[0], "from": threshold[1]},
            "time": "per image: the scene's wall time divided by its views" if not request.deterministic_time else -1,
            # scenes with no rows because they failed (their targets count as misses); absent when none did
            **({"failed_scenes": failed} if failed else {}),
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


def work_dir(out: Path) -> Path:
    """The shard folder of an output CSV: ``<out>.parts`` beside it."""
    out = Path(out)
    return out.with_name(out.name + ".parts")


def shard_path(work: Path, scene_key: str) -> Path:
    """One shard per scene key (``/`` of a suffixed key becomes ``__``)."""
    return work / (re.sub(r"[^A-Za-z0-9_.-]", "__", scene_key) + ".json")


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
        from bop_cender.report.scene_figure import scene_figure

        scene_figure(
            output,
            scene,
            method.models,
            method.meshes,
            Path(vis_dir) / shard_path(Path(), scene.key).with_suffix(".png").name,
            judge_models=eval_models or None,
        )
    return SceneOutcome(scene.key, output.estimate)


def write_shard(path: Path, outcome: SceneOutcome, fingerprint: str) -> None:
    est = outcome.estimate
    content: dict[str, Any] = {
        "format": SHARD_FORMAT,
        "version": SHARD_VERSION,
        "fingerprint": fingerprint,
        "scene_key": outcome.scene_key,
        "error": outcome.error,
    }
    if est is not None:
        content.update(
            scene_id=est.scene_id,
            time_s=est.time_s,
            timings=dict(est.timings),
            objects=[
                {
                    "obj_id": o.obj_id,
                    "score": o.score,
                    "T_world_model": np.asarray(o.T_world_model).tolist(),
                    "image_scores": {str(k): v for k, v in o.image_scores.items()},
                }
                for o in est.objects
            ],
        )
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(content, indent=1))


def read_shard(
    path: Path, fingerprint: str, scene_key: str | None = None, obj_ids: Collection[int] | None = None
) -> SceneOutcome | None:
    """A shard made with the same settings, or None (missing, other settings, unreadable, or of a scene that failed:
    it is redone). With ``scene_key``, a shard of another scene is None too; with ``obj_ids`` (the dataset's target
    objects), one that estimates another object (an edited or foreign shard wrote rows of a carrier or of an unknown
    id, or ended the run in a traceback)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("format") != SHARD_FORMAT or data.get("fingerprint") != fingerprint:
        return None
    if data.get("error") is not None:
        return None  # a failed scene is tried again (its input may have been mended since)
    try:
        objects = tuple(
            ObjectEstimate(
                o["obj_id"],
                np.array(o["T_world_model"]),
                o["score"],
                {int(k): v for k, v in o.get("image_scores", {}).items()},
            )
            for o in data["objects"]
        )
        est = SceneEstimate(data["scene_key"], data["scene_id"], objects, data["time_s"], data["timings"])
    except (KeyError, TypeError, ValueError, BopCenderError):
        return None
    if scene_key is not None and est.scene_key != scene_key:  # (its scene_id follows: SceneEstimate checks them)
        return None
    if obj_ids is not None and any(o.obj_id not in obj_ids for o in est.objects):
        return None
    return SceneOutcome(data["scene_key"], est)


def results_dataset_name(dataset: str, data_root: str | Path | None) -> str:
    """The dataset part of a run's results file name: a ``--dataset bop`` folder's own name where it is a BOP dataset's
    (``lmo``: ``score`` then takes LM-O's toolkit constants), else ``dataset``."""
    if dataset == "bop" and data_root is not None:
        folder = Path(data_root).resolve().name
        if folder in TOOLKIT_TEST_WIDTHS:
            return folder
    return dataset


def _check_request(request: RunRequest) -> None:
    from bop_cender.results.files import default_result_filename, name_contradiction, parse_result_filename

    _check_source(request.heatmaps)
    if request.workers < 1:
        raise ConfigError(f"expected at least 1 worker, got {request.workers}", field="--workers")
    if request.threads < 1:
        raise ConfigError(f"expected at least 1 thread, got {request.threads}", field="--threads")
    if request.threads > 1 and request.workers > 1:
        raise ConfigError(
            f"--threads {request.threads} is for one process; with --workers {request.workers} each process has one"
            " thread (give one of the two)",
            field="--threads",
        )
    request.config.poses.check_refinable("poses.top_k")  # the CLI checked first, naming its option
    min_views = request.config.centers.min_views  # at least 1 (its bound)
    if request.max_views is not None and request.max_views < min_views:
        raise ConfigError(
            f"--max-views {request.max_views}: a 3D centre needs at least centers.min_views = {min_views} views, so"
            " no object could be found",
            field="--max-views",
        )
    if request.weights is not None and not uses_network(request.heatmaps):
        raise ConfigError(
            f"--weights {request.weights} is not used with --heatmaps {request.heatmaps} (no network runs); drop it"
            " or choose --heatmaps net",
            field="--weights",
        )
    if request.limit_scenes is not None and request.limit_scenes < 1:
        raise ConfigError(f"expected a positive number of scenes, got {request.limit_scenes}", field="--limit-scenes")
    out = Path(request.out)
    if out.is_dir():
        raise ConfigError(f"{out} is a directory; expected a results CSV path", field="--out")
    check_output_file(out)
    if request.vis_dir is not None:
        check_output_dir(request.vis_dir, "--vis")
    if out.suffix != ".csv":
        raise ConfigError(f"expected a .csv file name, got {out.name!r}", field="--out")
    name = parse_result_filename(out.name)
    contradiction = name_contradiction(name, request.dataset, request.split)
    dataset_name = results_dataset_name(request.dataset, request.data_root)
    named_by_folder = dataset_name != request.dataset  # a BOP dataset's own folder
    if (
        contradiction is None and named_by_folder and name.dataset not in (dataset_name, "bop")
    ):  # score takes its constants
        contradiction = f"the file name says dataset {name.dataset!r}, the data is the BOP dataset {dataset_name!r}"
    if contradiction is not None:
        raise ConfigError(
            f"{contradiction}; `score` reads the data from the name: name it"
            f" {default_result_filename(name.method, dataset_name, request.split)}",
            field="--out",
        )


def _execute(request: RunRequest, dataset: Dataset, keys: list[str]):
    """Yield a :class:`SceneOutcome` per key as scenes finish (in order with one worker)."""
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
            method = build_method(request, dataset, cost_threads=max(1, min(2, os.cpu_count() or 1)))
            with compiled_threads(request.threads):
                for key in keys:
                    yield estimate_scene(
                        method, dataset.scene(key), request.vis_dir, request.max_views, dataset.eval_models
                    )
        finally:
            torch.set_num_threads(threads)
        return
    build_method(request, dataset)  # a bad request fails here, once, before any process starts
    ctx = get_context("spawn")
    workers = min(request.workers, len(keys))
    with ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_worker, initargs=(request,)) as pool:
        futures = [pool.submit(_worker_scene, key) for key in keys]
        for future in as_completed(futures):
            yield future.result()


@dataclass
class _WorkerState:
    """What a worker process builds once (in :func:`_init_worker`) and uses for each of its scenes."""

    request: RunRequest
    dataset: Dataset
    method: CenDerNet


_STATE: list[_WorkerState] = []  # one entry in a worker process, set by its initializer


def _init_worker(request: RunRequest) -> None:
    """Worker process start: one torch thread (the processes share the cores), the dataset, the method."""
    import torch

    _exit_with_parent()
    torch.set_num_threads(1)
    # the run's process has said every dataset warning already (it opens the data, reads every mesh and scene first):
    # each worker repeating them, in Python's raw format, said each one N + 1 times
    warnings.simplefilter("ignore", DatasetWarning)
    dataset = open_run_dataset(request)
    _STATE[:] = [_WorkerState(request, dataset, build_method(request, dataset))]


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
    state = _STATE[0]
    return estimate_scene(
        state.method, state.dataset.scene(key), state.request.vis_dir, state.request.max_views,
        state.dataset.eval_models,
    )  # fmt: skip
