"""BOP'19 localisation scoring on plain typed inputs: top-n cut, valid GTs, greedy matching, recall, AR.

Follows the toolkit (docs/evaluation.md; ``eval_calc_errors.py``,
``eval_calc_scores.py``, ``pose_matching.match_poses``, ``score.calc_localization_scores``,
``eval_bop19_pose.py``). Nothing here loads files: a scorer loads the dataset and the results CSV,
calls :func:`select_top_n`, computes errors (``pose_errors.py``, ``vsd.py``) for the kept estimates
against every GT of the same object in the image, normalises them with :func:`normalize_by_diameter`
/ :func:`normalize_by_image_width`, and then calls :func:`valid_gts`, :func:`match`, :func:`recall`
and :func:`average_recalls`.

Matching runs every (variant, threshold) at once: an estimate's error for one GT may be a scalar
or a vector of V variants (VSD: one value per tau), and K thresholds give V x K independent greedy
matchings, as the toolkit's 100 + 10 + 10 separate runs do.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Generic, Protocol, TypeVar

import numpy as np

from bop_cender.data.targets_file import SceneId, Target

#: Thresholds of correctness, with np.arange's float noise (0.15000000000000002) kept on purpose.
VSD_THRESHOLDS: np.ndarray = np.arange(0.05, 0.51, 0.05)
MSSD_THRESHOLDS: np.ndarray = np.arange(0.05, 0.51, 0.05)
MSPD_THRESHOLDS: np.ndarray = np.arange(5, 51, 5)
#: MSPD is normalised to a 640 px wide image (error * 640 / width).
MSPD_REFERENCE_WIDTH = 640.0

#: ``(scene_id, im_id, gt_id)``; gt_id is the index in the image's ``scene_gt`` list.
GtKey = tuple[SceneId, int, int]


@dataclass(frozen=True)
class GtInstance:
    """A GT instance of an image, with its ``scene_gt_info.json`` visible fraction."""

    scene_id: SceneId
    im_id: int
    gt_id: int
    obj_id: int
    visib_fract: float

    @property
    def key(self) -> GtKey:
        return (self.scene_id, self.im_id, self.gt_id)


@dataclass
class EstimateErrors:
    """Normalised errors of one kept estimate against the GT instances of its object in its image.

    Attributes:
        est_id: index of the estimate within its (scene, im, obj) group in file order (the toolkit's).
        score: the estimate's confidence.
        errors: gt_id -> error (MSSD / diameter, MSPD * 640 / width) or ``(V,)`` errors (VSD per tau).
    """

    scene_id: SceneId
    im_id: int
    obj_id: int
    est_id: int
    score: float
    errors: dict[int, float | np.ndarray] = field(default_factory=dict)


class Scored(Protocol):
    """Anything with the BOP results columns used by the top-n cut."""

    scene_id: SceneId
    im_id: int
    obj_id: int
    score: float


EstT = TypeVar("EstT", bound=Scored)


@dataclass(frozen=True)
class SelectedEstimate(Generic[EstT]):
    """An estimate kept by the top-n cut, with its toolkit ``est_id`` (index in its group, file order)."""

    est_id: int
    estimate: EstT


@dataclass(frozen=True)
class Matches:
    """Greedy matching of every (variant, threshold) over the valid GTs.

    Attributes:
        gts: the valid GT instances, ``(G,)``.
        thresholds: ``(K,)`` thresholds of correctness.
        est_ids: ``(V, K, G)`` est_id matched to each GT, -1 if none.
        errors: ``(V, K, G)`` error of that match, NaN if none.
    """

    gts: tuple[GtInstance, ...]
    thresholds: np.ndarray
    est_ids: np.ndarray
    errors: np.ndarray

    @property
    def tp_counts(self) -> np.ndarray:
        """``(V, K)`` number of matched (true-positive) GTs."""
        return np.count_nonzero(self.est_ids >= 0, axis=-1)


def select_top_n(estimates: Sequence[EstT], targets: Sequence[Target], n_top: int = -1) -> list[SelectedEstimate[EstT]]:
    """The estimates the toolkit evaluates, per target, highest score first.

    Estimates are grouped by (scene, im, obj) in file order (``est_id`` = index in the group), each
    group sorted by score descending with a stable sort (ties keep file order) and cut to
    ``inst_count`` (``n_top = -1``, BOP'19), to all (``0``) or to ``n_top``. Groups that are not a
    target are ignored. A repeated target keeps its first position and its last ``inst_count``.
    """
    groups: dict[tuple[SceneId, int, int], list[SelectedEstimate[EstT]]] = {}
    for est in estimates:
        group = groups.setdefault((est.scene_id, est.im_id, est.obj_id), [])
        group.append(SelectedEstimate(len(group), est))
    counts = {(t.scene_id, t.im_id, t.obj_id): t.inst_count for t in targets}
    kept: list[SelectedEstimate[EstT]] = []
    for key, inst_count in counts.items():
        n = inst_count if n_top == -1 else (None if n_top == 0 else n_top)
        ranked = sorted(groups.get(key, []), key=lambda s: s.estimate.score, reverse=True)
        kept.extend(ranked[slice(0, n)])
    return kept


def valid_gts(gts: Iterable[GtInstance], targets: Sequence[Target], visib_gt_min: float = -1.0) -> list[GtInstance]:
    """The GT instances that count as targets (recall's denominator), per target image.

    ``visib_gt_min < 0`` (BOP'19): in each target image the GTs are sorted by ``visib_fract``
    descending, stable over gt_id (ties keep the lower gt_id first), and the first ``inst_count``
    of each target object are valid. ``visib_gt_min >= 0``: valid iff the object is a target of the
    image and ``visib_fract >= visib_gt_min``. GTs of non-target images are never valid.

    Returns:
        valid instances, by target image (targets' order), then gt_id.
    """
    per_image: dict[tuple[SceneId, int], dict[int, int]] = {}
    for t in targets:
        per_image.setdefault((t.scene_id, t.im_id), {})[t.obj_id] = t.inst_count
    by_image: dict[tuple[SceneId, int], list[GtInstance]] = {}
    for g in gts:
        by_image.setdefault((g.scene_id, g.im_id), []).append(g)
    valid: list[GtInstance] = []
    for image, inst_counts in per_image.items():
        im_gts = sorted(by_image.get(image, []), key=lambda g: g.gt_id)
        if visib_gt_min >= 0:
            chosen = {g.gt_id for g in im_gts if g.obj_id in inst_counts and g.visib_fract >= visib_gt_min}
        else:
            to_add = dict(inst_counts)
            chosen = set()
            for g in sorted(im_gts, key=lambda g: g.visib_fract, reverse=True):
                if to_add.get(g.obj_id, 0) > 0:
                    chosen.add(g.gt_id)
                    to_add[g.obj_id] -= 1
        valid.extend(g for g in im_gts if g.gt_id in chosen)
    return valid


def match(
    estimates: Iterable[EstimateErrors], valid: Sequence[GtInstance], thresholds: np.ndarray | Sequence[float]
) -> Matches:
    """Greedy BOP matching per (image, object), for every variant and threshold at once.

    Estimates go in decreasing score order (stable: ties by est_id, i.e. file order). Each takes,
    among the valid GTs not matched yet, the one with the lowest error strictly below the threshold
    (ties: lowest gt_id); it matches at most one GT, and no match is revisited. GT ids absent from
    ``valid`` are ignored; errors must be normalised already.

    Args:
        estimates: the kept estimates' errors; every error is a scalar or a ``(V,)`` vector (same V throughout).
        valid: the valid GT instances (:func:`valid_gts`).
        thresholds: ``(K,)`` thresholds of correctness.

    Returns:
        :class:`Matches` with ``(V, K, G)`` arrays.
    """
    ths = np.asarray(thresholds, dtype=np.float64).reshape(-1)
    index = {g.key: i for i, g in enumerate(valid)}
    groups: dict[tuple[SceneId, int, int], list[EstimateErrors]] = {}
    n_variants: int | None = None
    for est in estimates:
        groups.setdefault((est.scene_id, est.im_id, est.obj_id), []).append(est)
        for err in est.errors.values():
            v = np.size(err)
            if n_variants is None:
                n_variants = v
            elif v != n_variants:
                raise ValueError(f"match: errors have {v} variants where others have {n_variants} (est {est.est_id})")
    V = n_variants or 1
    est_ids = np.full((V, len(ths), len(valid)), -1, dtype=np.int64)
    errors = np.full((V, len(ths), len(valid)), np.nan)
    for (scene_id, im_id, _), group in groups.items():
        _match_group(group, scene_id, im_id, index, ths, V, est_ids, errors)
    return Matches(tuple(valid), ths, est_ids, errors)


def recall(matches: Matches, n_targets: int | None = None) -> np.ndarray:
    """``(V, K)`` recall = matched valid GTs / ``n_targets`` (default: the valid GTs), pooled over the dataset;
    0 when there is no target (``score.calc_recall``)."""
    n = len(matches.gts) if n_targets is None else n_targets
    if n == 0:
        return np.zeros(matches.est_ids.shape[:2])
    return matches.tp_counts / float(n)


def bop19_scores(
    vsd_recalls: np.ndarray | None, mssd_recalls: np.ndarray, mspd_recalls: np.ndarray
) -> dict[str, float | None]:
    """BOP'19 AR (and the paper's strict figures) from the recall tables, in the toolkit's order of averaging.

    Args:
        vsd_recalls: ``(taus, thresholds)`` (10 x 10 in BOP'19), averaged tau-major like the toolkit's list;
            None without test depth (then ``AR_VSD`` and ``AR`` are None).
        mssd_recalls, mspd_recalls: ``(thresholds,)``; a leading variant axis of 1 (from :func:`recall`) is fine.

    Returns:
        ``AR``, ``AR_VSD``, ``AR_MSSD``, ``AR_MSPD``, ``AR_MSPD<5px`` and ``AR_MSSD<5%`` (recall at the first threshold).
    """
    mssd_r = np.asarray(mssd_recalls, dtype=np.float64).reshape(-1)
    mspd_r = np.asarray(mspd_recalls, dtype=np.float64).reshape(-1)
    ar_mssd, ar_mspd = float(np.mean(mssd_r)), float(np.mean(mspd_r))
    ar_vsd = None if vsd_recalls is None else float(np.mean(np.asarray(vsd_recalls, dtype=np.float64).reshape(-1)))
    return {
        "AR": None if ar_vsd is None else float(np.mean([ar_vsd, ar_mssd, ar_mspd])),
        "AR_VSD": ar_vsd,
        "AR_MSSD": ar_mssd,
        "AR_MSPD": ar_mspd,
        "AR_MSPD<5px": float(mspd_r[0]),
        "AR_MSSD<5%": float(mssd_r[0]),
    }


def normalize_by_diameter(error: float | np.ndarray, diameter: float) -> float | np.ndarray:
    """MSSD (or ADD/ADI) as a fraction of the diameter: ``error / diameter``, the toolkit's operation."""
    return error / float(diameter)


def normalize_by_image_width(error: float | np.ndarray, width: int) -> float | np.ndarray:
    """MSPD on a 640 px wide image: ``(640.0 / width) * error``, in the toolkit's operation order.

    ``width`` is the dataset's image width constant (T-LESS Primesense: 720), not the actual image's.
    """
    return (MSPD_REFERENCE_WIDTH / width) * error


# --------------------------------------------------------------------------------------------- helpers


def _match_group(
    group: list[EstimateErrors],
    scene_id: SceneId,
    im_id: int,
    index: dict[GtKey, int],
    ths: np.ndarray,
    V: int,
    est_ids: np.ndarray,
    errors: np.ndarray,
) -> None:
    """Greedy matching of one (image, object) group, writing into ``est_ids`` / ``errors`` ``(V, K, G)``."""
    gt_ids = sorted({g for e in group for g in e.errors if (scene_id, im_id, g) in index})
    if not gt_ids:
        return
    cols = np.array([index[(scene_id, im_id, g)] for g in gt_ids])
    err = np.full((len(group), V, len(gt_ids)), np.inf)
    for i, e in enumerate(group):
        for j, g in enumerate(gt_ids):
            if g in e.errors:
                err[i, :, j] = np.asarray(e.errors[g], dtype=np.float64).reshape(V)
    order = sorted(range(len(group)), key=lambda i: (-group[i].score, group[i].est_id))
    taken = np.zeros((V, len(ths), len(gt_ids)), dtype=bool)
    v_idx, k_idx = np.indices((V, len(ths)))
    for i in order:
        cand = (err[i][:, None, :] < ths[None, :, None]) & ~taken  # (V, K, G_group)
        best = np.where(cand, err[i][:, None, :], np.inf).argmin(axis=2)  # first (lowest gt_id) minimum
        hit = cand[v_idx, k_idx, best]
        if not hit.any():
            continue
        hv, hk, hj = v_idx[hit], k_idx[hit], best[hit]
        taken[hv, hk, hj] = True
        est_ids[hv, hk, cols[hj]] = group[i].est_id
        errors[hv, hk, cols[hj]] = err[i, hv, hj]
