"""What a run is asked to do (:class:`RunRequest`) and every check it passes before its first scene.

A run that did its work and then failed in ``score``, or wrote a CSV of nothing but empty rows, cost its user the
whole run: so the request's own values (output name, counts, heatmap source) are checked before any data is
opened (:func:`check_request`), and the data's (meshes, views per scene, the targets file) once it is, before any
scene is estimated. Each refusal is one :class:`~bop_cender.errors.ConfigError` naming the option to change.
"""

from __future__ import annotations

import hashlib
import json
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from bop_cender.cluster import check_executor
from bop_cender.data.bop_io import check_output_dir, check_output_file
from bop_cender.data.industrial import config_layout
from bop_cender.data.types import Dataset, Scene
from bop_cender.errors import BopCenderError, ConfigError, DatasetWarning
from bop_cender.eval.toolkit_constants import TOOLKIT_TEST_WIDTHS
from bop_cender.meshes import MeshCache
from bop_cender.method import CenDerNetConfig
from bop_cender.progress import progress_bar

if TYPE_CHECKING:  # the network code loads only where a run uses a network
    from bop_cender.net.weights import NetWeights

HEATMAP_SOURCES = ("oracle", "net", "oracle-centers", "oracle-curvature")
"""Heatmap sources of ``run``: the oracle, the network, or the two mixed (ablations): ``oracle-centers`` takes
the centres from the oracle and the curvature from the network, ``oracle-curvature`` the reverse."""


#: The tasks a run can do, and the BOP protocol that scores each.
TASKS = {"localization": "bop19", "detection": "bop24"}


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
        workers: processes (``executor`` ``local``) or Ray actors (``ray``); scenes are spread over them. None: the
            executor's default (``local``: one process; ``ray``: one actor per CPU of the cluster, at most one per
            scene).
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
        task: ``localization`` (BOP'19: the instance counts and objects of each image are known) or ``detection``
            (BOP'24/'25: neither is; the config must not use them, :data:`TASKS`); the sidecar names the protocol
            the file is for (``bop19`` / ``bop24``), so ``score FILE.csv`` needs no flag.
        executor: where the scenes run (:data:`~bop_cender.cluster.EXECUTORS`): ``local`` (this process or
            ``workers`` processes of this machine) or ``ray`` (actors on a Ray cluster,
            :mod:`~bop_cender.runner.ray_executor`). Not in the fingerprint: a run resumed on another executor keeps
            its shards.
        address: the Ray cluster of ``executor`` ``ray``: ``auto`` (the one running on this machine) or
            ``HOST:PORT`` of its head; None: a Ray instance started on this machine for the run.
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
    workers: int | None = 1
    limit_scenes: int | None = None
    resume: bool = False
    deterministic_time: bool = False
    device: str = "cpu"
    pose_device: str = "cpu"
    vis_dir: Path | None = None
    max_views: int | None = None
    threads: int = 1
    task: str = "localization"
    executor: str = "local"
    address: str | None = None

    def __post_init__(self) -> None:
        if self.config is None:
            config = CenDerNetConfig.for_dataset(config_layout(self.dataset, self.data_root, self.split))
            object.__setattr__(self, "config", config.for_task(self.task) if self.task in TASKS else config)
        if self.task not in TASKS:
            raise ConfigError(f"expected one of {', '.join(TASKS)}, got {self.task!r}", field="--task")
        if self.task == "detection" and (self.config.known_counts or self.config.known_object_ids):
            raise ConfigError(
                "6D detection tells the method neither how many instances an image holds nor which objects:"
                " known_counts and known_object_ids must be false",
                field="--task",
            )

    @property
    def protocol(self) -> str:
        """The BOP protocol the results are for: ``bop19`` (localization) or ``bop24`` (detection)."""
        return TASKS[self.task]

    def fingerprint(self, weights: NetWeights | None = None) -> str:
        """What a shard depends on: data, heatmap source, seed and config (not out, workers, executor or resume).

        ``weights``: the request's weights as read for the run (their file's digest is taken from them: the file is
        not read again); None: the file named by ``self.weights`` is read for it."""
        known = weights.sha256 if weights is not None else None
        key = {
            "dataset": self.dataset,
            "data_root": str(Path(self.data_root).resolve()) if self.data_root else None,
            "split": self.split,
            "n_views": self.n_views,
            "model_type": self.model_type,
            "heatmaps": self.heatmaps,
            "weights": known if known is not None else _file_digest(self.weights),
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


def uses_network(heatmaps: str) -> bool:
    """Whether the heatmap source ``heatmaps`` (one of :data:`HEATMAP_SOURCES`) runs the network."""
    return heatmaps in HEATMAP_SOURCES and heatmaps != "oracle"


def check_source(heatmaps: str) -> None:
    """Refuse a heatmap source other than :data:`HEATMAP_SOURCES` (an API caller's: the CLI offers only those)."""
    if heatmaps not in HEATMAP_SOURCES:
        raise ConfigError(
            f"unknown heatmap source {heatmaps!r}; expected one of {', '.join(HEATMAP_SOURCES)}", field="--heatmaps"
        )


def resolve_weights(request: RunRequest) -> RunRequest:
    """``request`` with ``weights`` set to a file: the given one, or the shipped weights of the dataset kind."""
    if not uses_network(request.heatmaps) or request.weights is not None:
        return request
    from bop_cender.net.weights import shipped_weights_path

    return replace(request, weights=str(shipped_weights_path(request.dataset)))


def results_dataset_name(dataset: str, data_root: str | Path | None) -> str:
    """The dataset part of a run's results file name: a ``--dataset bop`` folder's own name where it is a BOP dataset's
    (``lmo``: ``score`` then takes LM-O's toolkit constants), else ``dataset``."""
    if dataset == "bop" and data_root is not None:
        folder = Path(data_root).resolve().name
        if folder in TOOLKIT_TEST_WIDTHS:
            return folder
    return dataset


def check_request(request: RunRequest) -> None:
    """The request's own values, before any data is opened: heatmap source, counts, ``--max-views``, ``--weights``
    without a network, and an output (and ``--vis`` folder) that can be written and that ``score`` will read as this
    run's dataset and split.

    Raises:
        ConfigError: the first problem, naming its option.
    """
    from bop_cender.results.files import default_result_filename, name_contradiction, parse_result_filename

    check_source(request.heatmaps)
    check_executor(request.executor, request.address, request.workers)
    if request.threads < 1:
        raise ConfigError(f"expected at least 1 thread, got {request.threads}", field="--threads")
    if request.threads > 1 and request.executor == "ray":
        raise ConfigError(
            f"--threads {request.threads} is for one process of this machine; each Ray actor has one thread"
            " (--workers sets how many actors)",
            field="--threads",
        )
    if request.threads > 1 and (request.workers or 1) > 1:
        raise ConfigError(
            f"--threads {request.threads} is for one process; with --workers {request.workers} each process has one"
            " thread (give one of the two)",
            field="--threads",
        )
    request.config.poses.check_refinable("poses.candidates.top_k")  # the CLI checked first, naming its option
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


def loadable_scenes(dataset: Dataset, keys: list[str], progress: bool) -> list[Scene]:
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


def check_views(request: RunRequest, keys: list[str], scenes: list[Scene]) -> None:
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


def check_targets(dataset: Dataset, scenes: list[Scene]) -> None:
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


def check_meshes(dataset: Dataset) -> None:
    """Every model's mesh read and checked once, before any scene (:meth:`~bop_cender.meshes.MeshCache.arrays`: a
    mesh of another size than its ``models_info.json`` entry, a broken PLY): found by the first scene to use it, such
    a mesh failed every scene after its network pass, each with the same error."""
    meshes = MeshCache(dataset.models)
    for obj_id in dataset.models:
        meshes.arrays(obj_id)
