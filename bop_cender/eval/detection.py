"""BOP'24/'25 6D-detection scoring on plain typed inputs: the per-image cap, greedy matching, COCO-style AP, mAP.

Reimplemented from the official toolkit's published protocol (``scripts/eval_bop24_pose.py``, which runs
``eval_calc_errors.py`` and ``eval_calc_scores.py`` with ``--eval_mode=detection``; ``inout.load_bop_results``,
``pose_matching.match_poses``, ``score.calc_pose_detection_scores`` and ``score.calc_ap``; docs/evaluation.md):

1. **Cap**: per image, the rows sorted by score, highest first (a stable sort: ties keep file order), the first
   100 kept (200 for ``xyzibd``), the rest cut (:func:`cap_per_image`). Every row counts towards its image's cap,
   also rows that are ignored later (other images, objects the image does not hold).
2. **Evaluated estimates**: of the kept rows, those of a target image whose object has a GT instance in that
   image (any visibility); the others are ignored, neither hits nor false positives (the toolkit computes no error
   for them). Their order, which decides ties of equal score in the precision-recall curve: target images in the
   targets file's order (scenes by first appearance, then images), objects in the order of their first GT
   instance, estimates by score (stable).
3. **Greedy matching** per (image, object) and threshold (:func:`match_detections`): estimates by decreasing score
   (ties by ``est_id``, their index in the capped order) each take, among the GT instances of their object not
   taken yet (all of them, however little is visible), the one with the lowest error strictly below the threshold;
   equal errors go to the first GT in the toolkit's order, which is the order of ``gt_id`` as text (``"10"``
   before ``"2"``: its JSON files sort keys as strings).
4. **Per object and threshold** (:func:`average_precision`): GT instances under 10 % visible are neither hits nor
   misses, and an estimate matched to one is left out; the others are true positives (matched) or false
   positives (not matched); sorted by score (stable), precision and recall after each; AP is the mean over the 101
   recall points 0, 0.01, ..., 1 of the largest precision at a recall at least that point (0 where none).
5. **mAP**: per object the mean AP over the thresholds, per error type the mean over objects with at least one
   GT instance at least 10 % visible in the target images; ``bop24_mAP`` the mean of MSSD's and MSPD's,
   ``bop25_mAP`` MSSD's, ``bop25_mAP_mm`` MSSD's with thresholds in millimetres (:func:`detection_scores`).

Every mean is numpy's over the same values in the same order as the toolkit's, so the figures equal its to the
last bit where the errors do.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol, TypeVar

import numpy as np

#: The toolkit's thresholds of correctness (``eval_bop24_pose.py``): MSSD as a fraction of the object's diameter
#: (np.arange's float noise kept, 0.15000000000000002), MSSD in millimetres (BOP'25) and MSPD in pixels of a 640 px
#: wide image.
MSSD_THRESHOLDS: np.ndarray = np.arange(0.05, 0.51, 0.05)
MSSD_MM_THRESHOLDS: np.ndarray = np.arange(2, 21, 2).astype(np.float64)
MSPD_THRESHOLDS: np.ndarray = np.arange(5, 51, 5).astype(np.float64)
#: The error types in the order of the toolkit's keys: name -> (thresholds, scores-JSON key).
ERROR_TYPES: dict[str, tuple[np.ndarray, str]] = {
    "mssd": (MSSD_THRESHOLDS, "bop24_mAP_mssd"),
    "mssd_mm": (MSSD_MM_THRESHOLDS, "bop24_mAP_mssd_mm"),
    "mspd": (MSPD_THRESHOLDS, "bop24_mAP_mspd"),
}
#: The keys of the toolkit's ``scores_bop24.json``, in its order.
BOP24_KEYS = (
    "bop24_mAP_mssd",
    "bop24_mAP_mssd_mm",
    "bop24_mAP_mspd",
    "bop24_mAP",
    "bop25_mAP",
    "bop25_mAP_mm",
    "bop24_average_time_per_image",
)
#: Estimates kept per image (``max_num_estimates_per_image``), and the datasets with another cap.
MAX_ESTIMATES_PER_IMAGE = 100
MAX_ESTIMATES_PER_IMAGE_BY_DATASET = {"xyzibd": 200}
#: GT instances less visible than this are neither hits nor misses (``visib_gt_min``).
MIN_VISIB_FRACT = 0.1
#: The recall points of the COCO-style AP (``np.linspace(0, 1, 101)``).
RECALL_POINTS: np.ndarray = np.linspace(0.0, 1.0, 101, endpoint=True)


class Row(Protocol):
    """What the cap reads of a results row."""

    scene_id: int
    im_id: int
    obj_id: int
    score: float


RowT = TypeVar("RowT", bound=Row)


def max_estimates_per_image(dataset: str) -> int:
    """The toolkit's cap on estimates per image for ``dataset`` (100; ``xyzibd`` 200)."""
    return MAX_ESTIMATES_PER_IMAGE_BY_DATASET.get(dataset, MAX_ESTIMATES_PER_IMAGE)


@dataclass(frozen=True)
class Capped:
    """The rows the cap keeps, in the toolkit's order, and those it cuts.

    Attributes:
        kept: images in order of their first row, each image's rows by score (stable), at most the cap.
        cut: the rows beyond each image's cap (lowest scores; of equal scores, the later in the file).
    """

    kept: list
    cut: list


def cap_per_image(rows: Sequence[RowT], cap: int) -> Capped:
    """``inout.load_bop_results(..., max_num_estimates_per_image=cap)``: per image the ``cap`` best-scored rows."""
    if cap < 1:
        raise ValueError(f"the cap must be >= 1, got {cap}")
    images: dict[tuple[int, int], list[RowT]] = {}
    for row in rows:
        images.setdefault((row.scene_id, row.im_id), []).append(row)
    kept: list[RowT] = []
    cut: list[RowT] = []
    for image_rows in images.values():
        ranked = sorted(image_rows, key=lambda r: r.score, reverse=True)  # stable: ties keep file order
        kept.extend(ranked[:cap])
        cut.extend(ranked[cap:])
    return Capped(kept, cut)


def gt_order(gt_ids: Sequence[int]) -> list[int]:
    """GT ids in the order the toolkit's matching visits them: as text (``"10" < "2"``), from its JSON files."""
    return sorted(gt_ids, key=str)


def match_detections(errors: np.ndarray, scores: np.ndarray, thresholds: np.ndarray) -> np.ndarray:
    """Greedy matching of one (image, object) group at every threshold at once.

    Args:
        errors: ``(E, G)`` errors of the group's estimates (rows in ``est_id`` order) against its GT instances
            (columns in :func:`gt_order`); ``inf`` where no error was computed.
        scores: ``(E,)`` the estimates' scores.
        thresholds: ``(K,)`` thresholds of correctness (an error matches when strictly below).

    Returns:
        ``(E, K)`` int: the column of the GT each estimate takes at each threshold, -1 for none.
    """
    E, G = errors.shape
    K = len(thresholds)
    out = np.full((E, K), -1, dtype=np.int64)
    if E == 0 or G == 0:
        return out
    order = np.argsort(-np.asarray(scores, dtype=np.float64), kind="stable")  # by score, ties by est_id
    taken = np.zeros((K, G), dtype=bool)
    ths = np.asarray(thresholds, dtype=np.float64)[:, None]
    rows = np.arange(K)
    for i in order.tolist():
        cand = (errors[i][None, :] < ths) & ~taken  # (K, G)
        best = np.where(cand, errors[i][None, :], np.inf).argmin(axis=1)  # first minimum: the toolkit's strict <
        hit = cand[rows, best]
        if hit.any():
            taken[rows[hit], best[hit]] = True
            out[i, hit] = best[hit]
    return out


@dataclass(frozen=True)
class ApCurve:
    """One (object, threshold)'s average precision and its precision-recall curve.

    Attributes:
        ap: the average precision. n_gts: GT instances at least 10 % visible (recall's denominator).
        true_positives, false_positives: estimates counted as each (those matched to a less visible GT left out).
        precisions: ``(101,)`` the interpolated precision at each of :data:`RECALL_POINTS`.
    """

    ap: float
    n_gts: int
    true_positives: int
    false_positives: int
    precisions: np.ndarray


def average_precision(matched: np.ndarray, n_gts: int) -> ApCurve:
    """``score.calc_pose_detection_scores``' AP of one object at one threshold.

    Args:
        matched: ``(N,)`` bool, the counted estimates sorted by score (stable), True for a true positive.
        n_gts: recall's denominator, > 0.
    """
    matched = np.asarray(matched, dtype=bool)
    tp = np.cumsum(matched)
    fp = np.cumsum(~matched)
    recalls = tp / float(n_gts)
    precisions = tp / (tp + fp) if len(matched) else np.zeros(0)
    precision_at = interpolated_precisions(recalls, precisions)
    return ApCurve(float(np.mean(precision_at)), n_gts, int(tp[-1]) if len(tp) else 0,
                   int(fp[-1]) if len(fp) else 0, precision_at)  # fmt: skip


def interpolated_precisions(recalls: np.ndarray, precisions: np.ndarray) -> np.ndarray:
    """``score.calc_ap``'s 101 precisions: at each recall point the largest precision at a recall >= it.

    The curve gets the points (0, 0) and (1, 0) added, as the toolkit adds them (so a point above every recall
    reached reads 0). Vectorised: the recalls sorted, a running maximum from the right, one search per point.
    """
    mrec = np.concatenate(([0.0], np.asarray(recalls, dtype=np.float64), [1.0]))
    mpre = np.concatenate(([0.0], np.asarray(precisions, dtype=np.float64), [0.0]))
    order = np.argsort(mrec, kind="stable")
    mrec, mpre = mrec[order], mpre[order]
    best_from = np.maximum.accumulate(mpre[::-1])[::-1]  # max over mpre[j:] of the sorted curve
    first = np.searchsorted(mrec, RECALL_POINTS, side="left")  # first sorted recall >= the point
    out = np.zeros(len(RECALL_POINTS))
    inside = first < len(mrec)
    out[inside] = best_from[first[inside]]
    return out


@dataclass(frozen=True)
class ErrorTypeScores:
    """One error type's mAP and what it is made of.

    Attributes:
        mean_ap: the mean over :attr:`objects` of their mean AP over the thresholds; None without any object.
        thresholds: ``(K,)``. objects: object ids with at least one GT instance >= 10 % visible, ascending.
        object_ap: per object, its mean AP over the thresholds. curves: per object, ``K`` :class:`ApCurve`.
    """

    mean_ap: float | None
    thresholds: np.ndarray
    objects: tuple[int, ...]
    object_ap: dict[int, float]
    curves: dict[int, tuple[ApCurve, ...]]


def error_type_scores(
    obj_ids: np.ndarray,
    scores: np.ndarray,
    status: np.ndarray,
    n_gts: Mapping[int, int],
    thresholds: np.ndarray,
) -> ErrorTypeScores:
    """Per object and threshold the AP, per object their mean, and the mean over objects (the toolkit's loops).

    Args:
        obj_ids: ``(N,)`` each evaluated estimate's object, in the evaluated order (module doc, step 2).
        scores: ``(N,)`` their scores.
        status: ``(N, K)`` int8 per threshold: 1 true positive, 0 false positive, -1 left out (matched to a GT
            instance under 10 % visible).
        n_gts: object id -> GT instances >= 10 % visible in the target images (objects absent: none).
        thresholds: ``(K,)``.
    """
    objects = tuple(sorted(o for o, n in n_gts.items() if n > 0))
    object_ap: dict[int, float] = {}
    curves: dict[int, tuple[ApCurve, ...]] = {}
    for obj in objects:
        rows = np.flatnonzero(obj_ids == obj)
        ranked = rows[np.argsort(-scores[rows], kind="stable")]  # sorted(..., key=score, reverse=True)
        per_th = []
        for k in range(len(thresholds)):
            counted = status[ranked, k]
            per_th.append(average_precision(counted[counted >= 0] == 1, n_gts[obj]))
        curves[obj] = tuple(per_th)
        object_ap[obj] = float(np.mean([c.ap for c in per_th]))
    mean_ap = float(np.mean([object_ap[o] for o in objects])) if objects else None
    return ErrorTypeScores(mean_ap, np.asarray(thresholds, dtype=np.float64), objects, object_ap, curves)


def detection_scores(per_type: Mapping[str, ErrorTypeScores], time_per_image: float | None) -> dict[str, float | None]:
    """The toolkit's ``scores_bop24.json`` keys from the three error types' mAPs (None where one has no object).

    ``bop24_average_time_per_image`` is -1.0 when a time is unknown, as the toolkit writes it.
    """
    m = {name: s.mean_ap for name, s in per_type.items()}
    both = None if m["mssd"] is None or m["mspd"] is None else float(np.mean([m["mssd"], m["mspd"]]))
    return {
        "bop24_mAP_mssd": m["mssd"],
        "bop24_mAP_mssd_mm": m["mssd_mm"],
        "bop24_mAP_mspd": m["mspd"],
        "bop24_mAP": both,
        "bop25_mAP": None if m["mssd"] is None else float(np.mean([m["mssd"]])),
        "bop25_mAP_mm": None if m["mssd_mm"] is None else float(np.mean([m["mssd_mm"]])),
        "bop24_average_time_per_image": -1.0 if time_per_image is None else float(time_per_image),
    }


def time_per_image(rows: Sequence) -> tuple[float | None, list[str]]:
    """``check_consistent_timings`` on the capped rows: the mean over images of each image's first known time.

    Returns:
        (the mean, None when any row's time is unknown (negative) or there is none; the images whose known times
        differ by more than 0.001 s, which the toolkit refuses).
    """
    times: dict[tuple[int, int], float] = {}
    available = True
    problems: list[str] = []
    for row in rows:
        if row.time < 0:
            available = False
            continue
        key = (row.scene_id, row.im_id)
        first = times.setdefault(key, row.time)
        if abs(first - row.time) > 0.001:
            problems.append(f"scene {key[0]} image {key[1]}: times {first!r} and {row.time!r} s")
    if not available or not times:
        return None, problems
    return float(np.mean(list(times.values()))), problems
