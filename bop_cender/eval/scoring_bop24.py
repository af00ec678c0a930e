"""BOP'24/'25 6D-detection scoring end to end: results rows + a dataset split -> :class:`DetectionReport`.

The official ``scripts/eval_bop24_pose.py`` protocol in one process (:mod:`bop_cender.eval.detection` has the rules):

1. ground truth per image from the Dataset (:mod:`bop_cender.eval.ground_truth`), the target images
   (:func:`target_images`: ``test_targets_bop24.json``, else the images of ``test_targets_bop19.json``, else every
   image of the split) and every GT instance's visible fraction (``scene_gt_info.json``, else rendered);
2. the per-image cap on the rows (100 by score; ``xyzibd`` 200);
3. the evaluated estimates: kept rows of a target image whose object the image holds (the rest ignored, counted);
4. MSSD (mm, and / diameter) and MSPD (x 640 / width) of every (estimate, GT instance of its object) pair, by the
   same batched code as BOP'19 (:mod:`bop_cender.eval.pair_errors`);
5. greedy matching per (image, object) and threshold, AP per object and threshold, the mAPs.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bop_cender.data.layout import TARGETS_FILE, TARGETS_FILE_BOP24
from bop_cender.data.targets_file import read_image_targets
from bop_cender.data.types import Dataset
from bop_cender.errors import DatasetError, ResultsError
from bop_cender.eval.detection import (
    ERROR_TYPES,
    MIN_VISIB_FRACT,
    cap_per_image,
    detection_scores,
    error_type_scores,
    gt_order,
    match_detections,
    max_estimates_per_image,
    time_per_image,
)
from bop_cender.eval.detection_report import DetectionCounts, DetectionReport, EvaluatedEstimate
from bop_cender.eval.ground_truth import GroundTruth, ImageGt, collect_ground_truth
from bop_cender.eval.matching import normalize_by_image_width
from bop_cender.eval.pair_errors import Beyond, pair_errors
from bop_cender.eval.pairs import Pairs
from bop_cender.eval.scoring import image_width
from bop_cender.eval.targets import stored_visib
from bop_cender.eval.toolkit_constants import mspd_width
from bop_cender.eval.visibility import rendered_visib_fracts
from bop_cender.eval.vsd import VSD_TAUS
from bop_cender.meshes import MeshCache
from bop_cender.results.bop_csv import BopEstimate

#: Where the target images came from (the report's ``targets_source``).
SOURCE_BOP24 = "bop24_file"
SOURCE_BOP19 = "bop19_file"
SOURCE_ALL = "all_images"


@dataclass(frozen=True)
class TargetImages:
    """The images the detection task evaluates, in the toolkit's order (scenes by first appearance, then images).

    Attributes:
        keys: ``(scene_int, im_id)``. source: :data:`SOURCE_BOP24`, :data:`SOURCE_BOP19` or :data:`SOURCE_ALL`.
        note: one line for the report.
    """

    keys: tuple[tuple[int, int], ...]
    source: str
    note: str


def target_images(dataset: Dataset, gt: GroundTruth) -> TargetImages:
    """The target images: ``test_targets_bop24.json``; else the images of the BOP'19 file (what the toolkit uses when
    given it); else every loaded image (the synthetic sets, DIMO). Scenes in order of first appearance, then images.

    Target images of scenes not loaded (the scenes of a partial run, as BOP'19 scoring cuts its targets) are left
    out, and the note says how many.

    Raises:
        DatasetError: none of the target images is loaded (the loader has checked that each exists in the split).
    """
    path = dataset.root / TARGETS_FILE_BOP24
    if path.is_file():
        keys, source = read_image_targets(path), SOURCE_BOP24
        note = f"target images from {TARGETS_FILE_BOP24}"
    elif dataset.bop19_targets() is not None:
        path = dataset.root / TARGETS_FILE
        keys = list(dict.fromkeys((int(t.scene_id), t.im_id) for t in dataset.bop19_targets() or []))
        source, note = SOURCE_BOP19, f"no {TARGETS_FILE_BOP24}: the images of {TARGETS_FILE} (their objects not used)"
    else:
        keys, source = list(gt.images), SOURCE_ALL
        note = f"no {TARGETS_FILE_BOP24} or {TARGETS_FILE}: every image of the split is a target image"
    missing = [k for k in keys if k not in gt.images]
    if missing and len(missing) == len(keys):
        shown = ", ".join(f"scene {s} image {i}" for s, i in missing[:5]) + (" ..." if len(missing) > 5 else "")
        raise DatasetError(f"none of the target images is in the split as loaded ({shown})", file=path, field="im_id")
    if missing:  # the loaders load every target image, so these are of scenes left out (a partial run's sidecar)
        keys = [k for k in keys if k in gt.images]
        note += f"; {len(missing)} of scenes not loaded (a partial run) left out"
    by_scene: dict[int, list[tuple[int, int]]] = {}
    for key in keys:
        by_scene.setdefault(key[0], []).append(key)
    ordered = tuple(k for scene in by_scene.values() for k in scene)
    return TargetImages(ordered, source, f"{note}: {len(ordered)} images in {len(by_scene)} scenes")


def score_detections(
    rows: Sequence[BopEstimate],
    dataset: Dataset,
    *,
    progress: bool = True,
    source: str | Path | None = None,
    cap: int | None = None,
) -> DetectionReport:
    """Score BOP results rows on a dataset split with the BOP'24/'25 6D-detection protocol.

    Args:
        rows: the results (:func:`bop_cender.results.bop_csv.read_bop_results`), any order.
        dataset: the split the rows were estimated on.
        progress: progress bars on stderr.
        source: the results file, for messages.
        cap: estimates kept per image; default the toolkit's for the dataset (:func:`max_estimates_per_image`).

    Raises:
        DatasetError: the dataset's files are missing or inconsistent, or no GT instance is 10 % visible.
    """
    timings: dict[str, float] = {}
    clock = time.perf_counter()
    gt = collect_ground_truth(dataset, progress)
    images = target_images(dataset, gt)
    models = dataset.eval_models or dataset.models
    meshes = MeshCache(models)
    targetable = set(dataset.target_obj_ids)
    visib = stored_visib(gt)
    visib_source = "scene_gt_info.json"
    if visib is None:
        visib = rendered_visib_fracts([gt.images[k] for k in images.keys], meshes, progress)
        visib_source = "rendered from the GT poses (no scene_gt_info.json)"
    timings["ground_truth"] = time.perf_counter() - clock

    cap = max_estimates_per_image(dataset.name) if cap is None else cap
    capped = cap_per_image(list(rows), cap)
    mean_time, time_problems = time_per_image(capped.kept)
    if time_problems:
        raise ResultsError(
            f"{len(time_problems)} image(s) hold estimates whose times differ by more than 0.001 s (the toolkit"
            f" refuses such a file): {'; '.join(time_problems[:3])}",
            file=source,
            field="time",
        )
    groups, ignored = _evaluated_groups(capped.kept, gt, images.keys, targetable)
    evaluated = [row for _, _, group in groups for row in group]
    pairs, group_pairs = _pairs(groups, gt, visib)
    width = mspd_width(dataset.name, dataset.split_folder, image_width(gt, dataset))
    clock = time.perf_counter()
    raw = pair_errors(pairs, models, meshes, None, VSD_TAUS, progress, beyond=_beyond(models, width.value))
    timings["errors"] = time.perf_counter() - clock

    clock = time.perf_counter()
    diameters = np.array([models[int(o)].diameter for o in pairs.obj_id.tolist()], dtype=np.float64)
    values = {
        "mssd": raw.mssd / diameters,
        "mssd_mm": raw.mssd,
        "mspd": normalize_by_image_width(raw.mspd, width.value),
    }
    status = {name: np.zeros((len(evaluated), len(ths)), dtype=np.int8) for name, (ths, _) in ERROR_TYPES.items()}
    best_gt = np.full(len(evaluated), -1, dtype=np.int64)
    first = 0
    for (_key, _obj, group), (gt_ids, cols, visible) in zip(groups, group_pairs, strict=True):
        n = len(group)
        if gt_ids:
            scores = np.array([r.score for r in group], dtype=np.float64)
            for name, (ths, _) in ERROR_TYPES.items():
                errors = values[name][cols]  # (n, G)
                taken = match_detections(errors, scores, ths)
                hit = taken >= 0
                status[name][first : first + n] = np.where(hit, np.where(visible[np.maximum(taken, 0)], 1, -1), 0)
            best_gt[first : first + n] = np.asarray(gt_ids)[np.argmin(values["mssd_mm"][cols], axis=1)]
        first += n
    n_gts, hidden, visible = _instances(gt, images.keys, visib, targetable)
    obj_ids = np.array([r.obj_id for r in evaluated], dtype=np.int64)
    est_scores = np.array([r.score for r in evaluated], dtype=np.float64)
    per_type = {
        name: error_type_scores(obj_ids, est_scores, status[name], n_gts, ths) for name, (ths, _) in ERROR_TYPES.items()
    }
    if not per_type["mssd"].objects:
        raise DatasetError(
            f"no GT instance of a target object is at least {MIN_VISIB_FRACT:g} visible in the"
            f" {len(images.keys)} target images: nothing to detect, so no AP",
            file=dataset.root,
        )
    scores = detection_scores(per_type, mean_time)
    timings["matching"] = time.perf_counter() - clock
    records = _records(evaluated, pairs, raw.mssd, values, status, best_gt)
    counts = DetectionCounts(
        rows=len(rows),
        cut=len(capped.cut),
        cap=cap,
        not_target_image=ignored["not_target_image"],
        object_not_in_image=ignored["object_not_in_image"],
        unknown_object=sum(1 for r in rows if r.obj_id not in dataset.models),
        evaluated=len(evaluated),
        pairs=len(pairs),
        target_images=len(images.keys),
        gt_instances=sum(n_gts.values()),
        gt_instances_hidden=hidden,
    )
    return DetectionReport(
        scores=scores,
        per_type=per_type,
        counts=counts,
        dataset=dataset.name,
        split=dataset.split,
        root=str(dataset.root),
        results=None if source is None else str(source),
        targets_source=images.source,
        targets_note=images.note,
        visib_source=visib_source,
        mspd_width=width.value,
        mspd_width_source=width.source,
        gt_pose_source=gt.pose_source,
        records=records,
        timings=timings,
        visible_gts=visible,
        ground_truth=gt,
    )


# --------------------------------------------------------------------------------------------- helpers

#: Relative margin above the largest thresholds where errors stop being computed: a value that far is beyond every
#: threshold after its normalisation too (whose rounding is ~1e-16), so every hit and miss is the toolkit's.
BEYOND_MARGIN = 1e-6


def _beyond(models, width: float) -> Beyond:
    """The errors the protocol needs exactly: below its largest thresholds (0.5 diameter or 20 mm; 50 px at 640)."""
    mssd_ths, mspd_ths = ERROR_TYPES["mssd"][0], ERROR_TYPES["mspd"][0]
    mm = float(ERROR_TYPES["mssd_mm"][0].max())
    far = {o: max(float(mssd_ths.max()) * m.diameter, mm) * (1 + BEYOND_MARGIN) for o, m in models.items()}
    return Beyond(far, float(mspd_ths.max()) * width / 640.0 * (1 + BEYOND_MARGIN))


Group = tuple[tuple[int, int], int, list[BopEstimate]]


def _evaluated_groups(
    kept: list[BopEstimate], gt: GroundTruth, images: Sequence[tuple[int, int]], targetable: set[int]
) -> tuple[list[Group], dict[str, int]]:
    """The evaluated estimates grouped by (image, object) in the toolkit's order, and the ignored rows counted."""
    by_group: dict[tuple[int, int, int], list[BopEstimate]] = {}
    for row in kept:  # capped order: per image by score, so each group is by score with ties in file order
        by_group.setdefault((row.scene_id, row.im_id, row.obj_id), []).append(row)
    wanted = set(images)
    groups: list[Group] = []
    used = 0
    for key in images:
        objects = dict.fromkeys(g.obj_id for g in gt.images[key].instances if g.obj_id in targetable)
        for obj in objects:
            group = by_group.get((*key, obj))
            if group:
                groups.append((key, obj, group))
                used += len(group)
    not_target = sum(1 for r in kept if (r.scene_id, r.im_id) not in wanted)
    return groups, {"not_target_image": not_target, "object_not_in_image": len(kept) - used - not_target}


def _pairs(
    groups: list[Group], gt: GroundTruth, visib: dict
) -> tuple[Pairs, list[tuple[list[int], np.ndarray, np.ndarray]]]:
    """Every (evaluated estimate, GT instance of its object in its image) pair, and per group its GT ids in the
    toolkit's order, the ``(n, G)`` pair indices of its error matrix and ``(G,)`` whether each GT instance is at
    least 10 % visible."""
    images = list(gt.images.values())
    index = {im.key: i for i, im in enumerate(images)}
    est, img, gt_id, obj, T_e, T_g = [], [], [], [], [], []
    per_group = []
    k = 0
    for key, obj_id, group in groups:
        image: ImageGt = images[index[key]]
        instances = {g.gt_id: g for g in image.instances if g.obj_id == obj_id}
        ids = gt_order(list(instances))
        cols = np.zeros((len(group), len(ids)), dtype=np.int64)
        for r, row in enumerate(group):
            for c, g in enumerate(ids):
                cols[r, c] = len(est)
                est.append(k + r)
                img.append(index[key])
                gt_id.append(g)
                obj.append(obj_id)
                T_e.append(row.T_cam_model)
                T_g.append(instances[g].T_cam_model)
        fracts = visib.get(key, {})
        per_group.append((ids, cols, np.array([fracts.get(g, 0.0) >= MIN_VISIB_FRACT for g in ids], dtype=bool)))
        k += len(group)
    as_int = lambda v: np.asarray(v, dtype=np.int64)  # noqa: E731
    poses = lambda v: np.stack(v) if v else np.zeros((0, 4, 4))  # noqa: E731
    return Pairs(as_int(est), as_int(img), as_int(gt_id), as_int(obj), poses(T_e), poses(T_g), images), per_group


def _instances(
    gt: GroundTruth, images: Sequence[tuple[int, int]], visib: dict, targetable: set[int]
) -> tuple[dict[int, int], int, tuple[tuple[int, int, int, int], ...]]:
    """Per target object, its GT instances at least 10 % visible in the target images (recall's denominator), how
    many target-object instances are less visible (neither hits nor misses), and the visible ones'
    ``(scene_id, im_id, gt_id, obj_id)``."""
    counts: dict[int, int] = {}
    visible: list[tuple[int, int, int, int]] = []
    hidden = 0
    for key in images:
        fracts = visib.get(key, {})
        for g in gt.images[key].instances:
            if g.obj_id not in targetable:
                continue
            if fracts.get(g.gt_id, 0.0) >= MIN_VISIB_FRACT:
                counts[g.obj_id] = counts.get(g.obj_id, 0) + 1
                visible.append((key[0], key[1], g.gt_id, g.obj_id))
            else:
                hidden += 1
    return counts, hidden, tuple(visible)


def _records(evaluated, pairs: Pairs, mssd_mm, values, status, best_gt) -> list[EvaluatedEstimate]:
    """One record per evaluated estimate: its errors against its closest GT (by MSSD) and its hits per error type."""
    first_pair = {}
    for p in range(len(pairs)):
        first_pair.setdefault((int(pairs.est[p]), int(pairs.gt_id[p])), p)
    out = []
    for i, row in enumerate(evaluated):
        g = int(best_gt[i])
        p = first_pair.get((i, g))
        errs = (float(mssd_mm[p]), float(values["mssd"][p]), float(values["mspd"][p])) if p is not None else None
        out.append(
            EvaluatedEstimate(
                row.scene_id,
                row.im_id,
                row.obj_id,
                row.score,
                row.line,
                g,
                errs,
                {name: status[name][i] for name in status},
            )  # fmt: skip
        )
    return out
