"""BOP'19 localisation scoring end to end: results rows + a dataset split -> :class:`ScoreReport`.

The official pipeline (the toolkit's ``scripts/eval_bop19_pose.py`` and the scripts it starts; see
docs/evaluation.md) in one process:

1. ground truth per image from the Dataset (:mod:`bop_cender.eval.ground_truth`);
2. every row checked against the split: an unknown object, scene or image is an error naming the
   line; an image that exists but is not selected/target is ignored, as the toolkit ignores it;
3. targets (:mod:`bop_cender.eval.targets`): the targets file, else the ``visib_fract >= 0.1`` rule;
4. top-n per target (``n_top = -1``: ``inst_count``), est_id = index in its (scene, image, object) group;
5. raw errors of each kept estimate against every GT of its object in the image
   (:mod:`bop_cender.eval.pair_errors`): MSSD, MSPD and, with test depth, VSD;
6. normalisation: MSSD / diameter, MSPD x 640 / width (the toolkit's dataset constant, see
   :mod:`bop_cender.eval.toolkit_constants`);
7. valid GTs, greedy matching per threshold, recall pooled over the dataset, AR
   (:mod:`bop_cender.eval.matching`).

Without test depth (DIMO) VSD, AR_VSD and AR are None (not available); MSSD and MSPD stand alone.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bop_cender.data.layout import TARGETS_FILE
from bop_cender.data.types import Dataset, ObjectModel
from bop_cender.eval.detection import time_per_image
from bop_cender.eval.ground_truth import GroundTruth, collect_ground_truth
from bop_cender.eval.matching import (
    MSPD_THRESHOLDS,
    MSSD_THRESHOLDS,
    VSD_THRESHOLDS,
    EstimateErrors,
    GtInstance,
    Matches,
    SelectedEstimate,
    bop19_scores,
    match,
    normalize_by_image_width,
    recall,
    select_top_n,
    valid_gts,
)
from bop_cender.eval.pair_errors import PairErrors, pair_errors
from bop_cender.eval.pairs import Pairs
from bop_cender.eval.render_process import DepthRenderer
from bop_cender.eval.score_report import ScoreCounts, ScoreMetadata, ScoreReport
from bop_cender.eval.score_rows import check_rows, count_not_target, estimate_records, unmatched_reasons
from bop_cender.eval.targets import TargetSet, resolve_targets
from bop_cender.eval.toolkit_constants import Choice, mspd_width, vsd_delta_for
from bop_cender.eval.visibility import rendered_visib_fracts
from bop_cender.eval.vsd import VSD_TAUS
from bop_cender.meshes import MeshCache
from bop_cender.results.bop_csv import BopEstimate


def score_results(
    rows: Sequence[BopEstimate],
    dataset: Dataset,
    *,
    vsd_delta: float | None = None,
    n_top: int = -1,
    progress: bool = True,
    source: str | Path | None = None,
    renderer: DepthRenderer | None = None,
) -> ScoreReport:
    """Score BOP results rows on a dataset split with the BOP'19 localisation protocol.

    The steps, each a function with a typed value between them: :func:`gather` (ground truth, row checks,
    targets) -> :func:`pair_up` (top-n, pairs) -> :func:`compute_errors` (raw and normalised errors) ->
    :func:`match_errors` (valid GTs, greedy matching) -> :func:`build_report` (recalls, scores, records).

    Args:
        rows: the results (:func:`bop_cender.results.bop_csv.read_bop_results`), any order.
        dataset: the split the rows were estimated on.
        vsd_delta: VSD tolerance (mm); default the toolkit's (15, ITODD 5).
        n_top: estimates kept per target: -1 = ``inst_count`` (BOP'19), 0 = all, n > 0 = n.
        progress: progress bars on stderr (:mod:`bop_cender.progress`).
        source: the results file, for error messages.
        renderer: who renders for VSD (e.g. a :class:`~bop_cender.eval.render_process.RenderProcess`);
            None = worker threads of this process.

    Raises:
        ResultsError: rows naming objects, scenes or images that are not in the split (all listed).
        DatasetError: the dataset's files are missing or inconsistent.
    """
    timings: dict[str, float] = {}
    gathered = gather(rows, dataset, progress=progress, source=source, timings=timings)
    paired = pair_up(rows, gathered, n_top)
    errors = compute_errors(paired, gathered, dataset, vsd_delta, progress=progress, renderer=renderer, timings=timings)
    clock = time.perf_counter()
    matched = match_errors(paired, errors, gathered, n_top)
    report = build_report(rows, dataset, gathered, paired, errors, matched, n_top, source, timings)
    timings["matching"] = time.perf_counter() - clock
    return report


@dataclass(frozen=True, eq=False)
class Gathered:
    """Step 1: the split's ground truth, the rows checked against it, the targets.

    Attributes:
        gt: every selected image. unselected: rows for images on disk the split did not select (ignored).
        models: the evaluation models. meshes: their meshes, read once. targets: the BOP'19 targets.
    """

    gt: GroundTruth
    unselected: int
    models: Mapping[int, ObjectModel]
    meshes: MeshCache
    targets: TargetSet


@dataclass(frozen=True, eq=False)
class Paired:
    """Step 2: the estimates kept by the top-n cut and every (kept estimate, GT of its object) pair."""

    kept: list[SelectedEstimate[BopEstimate]]
    pairs: Pairs


@dataclass(frozen=True, eq=False)
class Errors:
    """Step 3: raw and normalised errors of every pair.

    Attributes:
        raw: MSSD (mm), MSPD (px), VSD ``(P, taus)`` or None. mssd, mspd: ``(P,)`` normalised (MSSD /
        diameter, MSPD x 640 / width). width: the MSPD width and its source. delta: VSD's delta, None without depth.
    """

    raw: PairErrors
    mssd: np.ndarray
    mspd: np.ndarray
    width: Choice
    delta: Choice | None


@dataclass(frozen=True, eq=False)
class Matched:
    """Step 4: greedy matches per threshold over the valid GTs, and recall's denominator."""

    mssd: Matches
    mspd: Matches
    vsd: Matches | None
    n_targets: int


def gather(
    rows: Sequence[BopEstimate],
    dataset: Dataset,
    *,
    progress: bool = True,
    source: str | Path | None = None,
    timings: dict[str, float] | None = None,
) -> Gathered:
    """Ground truth per image, every row checked against the split, the targets (file, scene_gt_info, rendered)."""
    timings = {} if timings is None else timings
    clock = time.perf_counter()
    gt = collect_ground_truth(dataset, progress)
    timings["ground_truth"] = time.perf_counter() - clock
    unselected = check_rows(rows, gt, dataset, source)
    models = dataset.eval_models or dataset.models
    meshes = MeshCache(models)
    clock = time.perf_counter()
    targets = resolve_targets(
        dataset.bop19_targets(), gt, dataset.target_obj_ids, lambda: rendered_visib_fracts(list(gt), meshes, progress),
        targets_path=dataset.root / TARGETS_FILE,
    )  # fmt: skip
    timings["targets"] = time.perf_counter() - clock
    return Gathered(gt, unselected, models, meshes, targets)


def pair_up(rows: Sequence[BopEstimate], gathered: Gathered, n_top: int = -1) -> Paired:
    """The top-n estimates per target and their pairs with the GTs of their object in their image."""
    kept = select_top_n(list(rows), gathered.targets.targets, n_top)
    return Paired(kept, _pairs(kept, gathered.gt))


def compute_errors(
    paired: Paired,
    gathered: Gathered,
    dataset: Dataset,
    vsd_delta: float | None = None,
    *,
    progress: bool = True,
    renderer: DepthRenderer | None = None,
    timings: dict[str, float] | None = None,
) -> Errors:
    """MSSD, MSPD and (with test depth) VSD of every pair, and their normalisation."""
    timings = {} if timings is None else timings
    gt, models, pairs = gathered.gt, gathered.models, paired.pairs
    width = mspd_width(dataset.name, dataset.split_folder, image_width(gt, dataset))
    has_depth = bool(gt.images) and all(im.depth_path is not None for im in gt)
    delta = vsd_delta_for(dataset.name, vsd_delta) if has_depth else None
    clock = time.perf_counter()
    raw = pair_errors(
        pairs, models, gathered.meshes, None if delta is None else delta.value, VSD_TAUS, progress, renderer
    )
    timings["errors"] = time.perf_counter() - clock
    diameters = np.array([models[int(o)].diameter for o in pairs.obj_id.tolist()], dtype=np.float64)
    mssd_n = raw.mssd / diameters  # the toolkit's e / diameter, per pair (normalize_by_diameter, vectorised)
    mspd_n = normalize_by_image_width(raw.mspd, width.value)
    return Errors(raw, mssd_n, mspd_n, width, delta)


def match_errors(paired: Paired, errors: Errors, gathered: Gathered, n_top: int = -1) -> Matched:
    """Valid GTs (the most visible instances of each target) and the greedy matching per metric and threshold."""
    targets = gathered.targets
    valid = valid_gts(_gt_instances(gathered.gt, targets), targets.targets)
    per_est = _estimate_errors(
        paired.kept, paired.pairs, {"mssd": errors.mssd, "mspd": errors.mspd, "vsd": errors.raw.vsd}
    )
    m_mssd = match(per_est["mssd"], valid, MSSD_THRESHOLDS)
    m_mspd = match(per_est["mspd"], valid, MSPD_THRESHOLDS)
    m_vsd = None if errors.raw.vsd is None else match(per_est["vsd"], valid, VSD_THRESHOLDS)
    return Matched(m_mssd, m_mspd, m_vsd, _targets_count(valid, n_top))


def build_report(
    rows: Sequence[BopEstimate],
    dataset: Dataset,
    gathered: Gathered,
    paired: Paired,
    errors: Errors,
    matched: Matched,
    n_top: int,
    source: str | Path | None = None,
    timings: dict[str, float] | None = None,
) -> ScoreReport:
    """Recalls pooled over the dataset, the BOP'19 scores, one record per evaluated estimate, the metadata."""
    r_mssd = recall(matched.mssd, matched.n_targets)[0]
    r_mspd = recall(matched.mspd, matched.n_targets)[0]
    r_vsd = None if matched.vsd is None else recall(matched.vsd, matched.n_targets)
    scores = bop19_scores(r_vsd, r_mssd, r_mspd)
    gt, targets, kept, pairs, raw = gathered.gt, gathered.targets, paired.kept, paired.pairs, errors.raw
    not_target = count_not_target(rows, targets.targets)
    records = estimate_records(kept, pairs, raw, errors.mssd, errors.mspd, matched.mssd, matched.mspd, matched.vsd)
    why = unmatched_reasons(records, matched.mssd)
    notes = [f"GT poses: {gt.pose_source}"]
    if errors.delta is None:
        notes.append("no test depth: VSD, AR_VSD and AR are not available; MSSD and MSPD stand alone")
    counts = ScoreCounts(
        rows=len(rows),
        not_target=not_target,
        unselected_images=gathered.unselected,
        evaluated=len(kept),
        beyond_top_n=len(rows) - len(kept) - not_target,
        pairs=len(pairs),
        targets=len(targets.targets),
        target_instances=matched.n_targets,
        target_images=len({(t.scene_id, t.im_id) for t in targets.targets}),
        missed_instances=why["missed"],
        unmatched_not_visible=why["not_visible"],
        unmatched_duplicate=why["duplicate"],
        unmatched_far=why["far"],
    )
    metadata = ScoreMetadata(
        dataset=dataset.name,
        split=dataset.split,
        root=str(dataset.root),
        results=None if source is None else str(source),
        n_top=n_top,
        mspd_width=errors.width.value,
        mspd_width_source=errors.width.source,
        vsd_delta=None if errors.delta is None else errors.delta.value,
        vsd_delta_source=None if errors.delta is None else errors.delta.source,
        vsd_renders=raw.vsd_renders,
        targets_source=targets.source,
        targets_note=targets.note,
        gt_pose_source=gt.pose_source,
        counts=counts,
        time_per_image=average_time_per_image(rows),
    )
    return ScoreReport(
        scores=scores,
        mssd_thresholds=np.asarray(MSSD_THRESHOLDS, np.float64),
        mspd_thresholds=np.asarray(MSPD_THRESHOLDS, np.float64),
        vsd_taus=np.asarray(VSD_TAUS, np.float64),
        vsd_thresholds=np.asarray(VSD_THRESHOLDS, np.float64),
        mssd_recalls=r_mssd,
        mspd_recalls=r_mspd,
        vsd_recalls=r_vsd,
        metadata=metadata,
        notes=notes,
        records=records,
        timings={} if timings is None else timings,
        ground_truth=gt,
        matches={
            "mssd": matched.mssd,
            "mspd": matched.mspd,
            **({"vsd": matched.vsd} if matched.vsd is not None else {}),
        },
    )


def average_time_per_image(rows: Sequence[BopEstimate]) -> float | None:
    """``bop19_average_time_per_image``: mean over images of their time; None if any row has time < 0 (the toolkit's
    ``check_consistent_timings``, shared with BOP'24: :func:`~bop_cender.eval.detection.time_per_image`; the reader
    has checked the times' consistency)."""
    return time_per_image(rows)[0]


# --------------------------------------------------------------------------------------------- helpers


def _pairs(kept: list, gt: GroundTruth) -> Pairs:
    """Every (kept estimate, GT instance of its object in its image) pair."""
    images = list(gt.images.values())
    index = {im.key: i for i, im in enumerate(images)}
    est, img, gt_id, obj, T_e, T_g = [], [], [], [], [], []
    for k, sel in enumerate(kept):
        row = sel.estimate
        i = index[(row.scene_id, row.im_id)]
        for g in images[i].instances:
            if g.obj_id == row.obj_id:
                est.append(k)
                img.append(i)
                gt_id.append(g.gt_id)
                obj.append(g.obj_id)
                T_e.append(row.T_cam_model)
                T_g.append(g.T_cam_model)
    as_int = lambda v: np.asarray(v, dtype=np.int64)  # noqa: E731
    poses = lambda v: np.stack(v) if v else np.zeros((0, 4, 4))  # noqa: E731
    return Pairs(as_int(est), as_int(img), as_int(gt_id), as_int(obj), poses(T_e), poses(T_g), images)


def _gt_instances(gt: GroundTruth, targets: TargetSet) -> list[GtInstance]:
    images = {(t.scene_id, t.im_id) for t in targets.targets}
    out = []
    for key in images:
        image = gt.images[key]
        fracts = targets.visib.get(key, {})
        out.extend(
            GtInstance(key[0], key[1], g.gt_id, g.obj_id, float(fracts.get(g.gt_id, 0.0))) for g in image.instances
        )
    return out


def _estimate_errors(kept: list, pairs: Pairs, errors: dict[str, np.ndarray | None]) -> dict[str, list[EstimateErrors]]:
    """Per metric, one EstimateErrors per kept estimate (gt_id -> normalised error; VSD a vector per tau)."""
    out: dict[str, list[EstimateErrors]] = {}
    for name, values in errors.items():
        if values is None:
            continue
        ests = [
            EstimateErrors(s.estimate.scene_id, s.estimate.im_id, s.estimate.obj_id, s.est_id, s.estimate.score)
            for s in kept
        ]
        for p in range(len(pairs)):
            ests[int(pairs.est[p])].errors[int(pairs.gt_id[p])] = values[p]
        out[name] = ests
    return out


def _targets_count(valid: list[GtInstance], n_top: int) -> int:
    """Recall's denominator: valid GTs, at most ``n_top`` per (image, object) when n_top > 0 (score.py)."""
    if n_top <= 0:
        return len(valid)
    counts: dict[tuple, int] = {}
    for g in valid:
        key = (g.scene_id, g.im_id, g.obj_id)
        counts[key] = counts.get(key, 0) + 1
    return int(sum(min(n_top, c) for c in counts.values()))


def image_width(gt: GroundTruth, dataset: Dataset) -> int:
    """The split's image width (its constant where the loader knows one, else the first image's; 640 without any)."""
    if dataset.image_size is not None:
        return int(dataset.image_size[0])
    return next(iter(gt)).width if len(gt) else 640
