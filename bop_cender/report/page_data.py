"""Everything one report page shows, gathered from a results CSV, its run sidecar and the data it was made on.

The scores are ``bop-cender score``'s own (:func:`~bop_cender.eval.score_file.score_file`, same data choice, same
protocol choice: the sidecar's ``extra.protocol``, else BOP'19), the breakdowns read off its matches
(:mod:`bop_cender.report.breakdown`), the paper's rows from the package's reference table, and the run's settings,
timings and failures from its sidecar (absent without one: the page says so).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bop_cender.data.types import Dataset
from bop_cender.errors import ResultsError
from bop_cender.eval.detection_report import DetectionReport
from bop_cender.eval.ground_truth import GroundTruth, ImageGt
from bop_cender.eval.score_file import ScoredFile, method_name, score_file
from bop_cender.eval.score_report import SCORE_KEYS
from bop_cender.report import breakdown
from bop_cender.report.breakdown import Group, Verdicts
from bop_cender.report.reference_table import PAPER_TABLES, reference_rows
from bop_cender.report.summary import MAP_KEYS, summary_lines
from bop_cender.results.bop_csv import BopEstimate, read_bop_results
from bop_cender.results.files import read_run_sidecar, sidecar_path


@dataclass(frozen=True)
class ScoreRow:
    """One row of the page's score table: a method, where its figures come from, its scores (None: not available)."""

    method: str
    source: str
    scores: dict[str, float | None]


@dataclass(frozen=True, eq=False)
class PageData:
    """What :func:`collect_page` gathers (see the module docstring).

    Attributes:
        results: the results CSV. sidecar: its run sidecar (None: none beside it). protocol: ``bop19`` or ``bop24``.
        scored: the scored file (report, data choice, dataset). score_keys: the score table's columns.
        score_rows: this file's row first, then the paper's (BOP'19 only: the paper reports no mAP).
        summary: the lines ``score`` prints under its table. objects: per-object breakdown (ascending id).
        scenes: per-scene breakdown, worst first. verdicts: per row line and missed GT instances.
        failed: failed scene -> reason (the sidecar's ``extra.failed_scenes``).
        run_timings: the sidecar's ``extra.timings`` (``stages``, ``wall``, ``scenes``), empty where not recorded.
        gt: the split's ground truth per image. rows: the file's rows.
        rgb_paths: per image ``(scene_id, im_id)`` its colour image (None: none).
    """

    results: Path
    sidecar: dict[str, Any] | None
    protocol: str
    scored: ScoredFile
    score_keys: tuple[str, ...]
    score_rows: list[ScoreRow]
    summary: list[str]
    objects: list[Group]
    scenes: list[Group]
    verdicts: Verdicts
    failed: dict[str, str]
    gt: GroundTruth
    rows: list[BopEstimate]
    rgb_paths: dict[tuple[int, int], Path | None]
    run_timings: dict[str, Any] = field(default_factory=dict)

    @property
    def dataset(self) -> Dataset:
        return self.scored.dataset

    def scene_images(self, key: str) -> list[ImageGt]:
        """The evaluated images of scene ``key``, in the split's order."""
        return [im for im in self.gt if im.scene_key == key]

    def rows_by_image(self) -> dict[tuple[int, int], list[BopEstimate]]:
        """The file's rows per image ``(scene_id, im_id)``, in file order."""
        out: dict[tuple[int, int], list[BopEstimate]] = {}
        for r in self.rows:
            out.setdefault((r.scene_id, r.im_id), []).append(r)
        return out


def collect_page(
    results: str | Path,
    *,
    progress: bool = False,
    scored: ScoredFile | None = None,
    **data_options: Any,
) -> PageData:
    """Score ``results`` as ``bop-cender score`` would (nothing written) and gather the page's content.

    ``data_options``: where the data are and how to score, as :func:`~bop_cender.eval.score_file.score_file` takes
    them (``dataset``, ``data_root``, ``split``, ``n_views``, ``seed``, ``model_type``, ``vsd_delta``, ``protocol``,
    ``open_data``): ``score``'s options. ``scored``: the file already scored by ``score_file`` (``run --score
    --report``), not scored again.

    Raises:
        ResultsError: the CSV or its sidecar is missing or malformed, a row names an unknown scene, image or object
            (each line named), or the sidecar's timings are not what a run writes.
        ConfigError: the data cannot be told (as ``score``: give ``--dataset``, ``--data-root``, ``--split``).
    """
    results = Path(results)
    if scored is None:
        scored = score_file(results, progress=progress, render_process=False, write=False, **data_options)
    sidecar = read_run_sidecar(results)
    extra = (sidecar or {}).get("extra", {})
    report = scored.report
    ds = scored.dataset
    gt = report.ground_truth
    assert gt is not None, "score_file's reports keep the ground truth they were scored against"
    scene_of = {im.key: im.scene_key for im in gt}
    keys = list(ds.scene_keys)
    rows = [ScoreRow(method_name(results), f"scored {results.name}", dict(report.scores))]
    if isinstance(report, DetectionReport):
        keys_shown: tuple[str, ...] = MAP_KEYS
        summary = report.summary_lines()
        objects = breakdown.objects_bop24(report)
        scenes = breakdown.scenes_bop24(report, scene_of, keys)
        verdicts = breakdown.verdicts_bop24(report)
    else:
        keys_shown = SCORE_KEYS
        meta = report.metadata
        rows += [ScoreRow(r.method, r.source, r.scores) for r in reference_rows(PAPER_TABLES, meta.dataset, meta.split)]
        summary = summary_lines(report)
        objects = breakdown.objects_bop19(report)
        scenes = breakdown.scenes_bop19(report, scene_of, keys)
        verdicts = breakdown.verdicts_bop19(report)
    views = {(key, v.im_id): v.rgb_path for key in keys for v in ds.scene(key).views if v.evaluated}
    rgb_paths = {im.key: views.get((im.scene_key, im.im_id)) for im in gt}
    return PageData(
        results=results,
        sidecar=sidecar,
        protocol=scored.protocol,
        scored=scored,
        score_keys=keys_shown,
        score_rows=rows,
        summary=[*summary, f"data: {scored.choice.origin}"],
        objects=objects,
        scenes=scenes,
        verdicts=verdicts,
        failed=dict(extra.get("failed_scenes") or {}),
        gt=gt,
        rows=read_bop_results(results, check_times=False),
        rgb_paths=rgb_paths,
        run_timings=run_timings(extra, results),
    )


def run_timings(extra: dict[str, Any], results: Path) -> dict[str, Any]:
    """The sidecar's ``extra.timings`` (written by ``bop-cender run``), checked: ``stages`` and each of ``scenes``
    map stage names to seconds, ``wall`` is seconds; ``{}`` where the run recorded none.

    Raises:
        ResultsError: naming the sidecar and the field that is not what a run writes.
    """
    timings = extra.get("timings")
    if timings is None:
        return {}
    where = {"file": sidecar_path(results)}

    def seconds(value: Any, name: str) -> None:
        if isinstance(value, bool) or not isinstance(value, int | float) or value < 0:
            raise ResultsError(f"expected seconds (a number >= 0), got {value!r}", field=name, **where)

    if not isinstance(timings, dict):
        raise ResultsError(f"expected an object, got {type(timings).__name__}", field="extra.timings", **where)
    stages = timings.get("stages", {})
    scenes = timings.get("scenes", {})
    if not isinstance(stages, dict) or not isinstance(scenes, dict):
        raise ResultsError("expected objects of seconds", field="extra.timings.stages / scenes", **where)
    for stage, value in stages.items():
        seconds(value, f"extra.timings.stages.{stage}")
    for key, per_stage in scenes.items():
        if not isinstance(per_stage, dict):
            raise ResultsError("expected an object of seconds per stage", field=f"extra.timings.scenes.{key}", **where)
        for stage, value in per_stage.items():
            seconds(value, f"extra.timings.scenes.{key}.{stage}")
    if "wall" in timings:
        seconds(timings["wall"], "extra.timings.wall")
    return timings
