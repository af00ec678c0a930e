"""Validation figures of stage 1: how well predicted center and curvature heatmaps match the GT ones.

Used by ``bop-cender train`` after every epoch and by ``bop-cender heatmaps``. Both figures measure what
the later stages see of a prediction, with the same detector and the same threshold:

- **Centers**: in each view and center channel, the peaks that stage 2 finds
  (:func:`bop_cender.centers.find_peaks`: ``peak_local_max`` above ``peak_threshold``, ``min_distance``
  ``peak_min_distance``, border included) against the peaks of the GT map (local maxima above
  ``gt_peak_threshold``; GT blobs have peak 1). Predicted and GT peaks of the same view and channel are
  matched one-to-one within ``pixel_tolerance`` pixels, as many pairs as possible and, among those, the
  smallest summed distance (Hungarian, :func:`scipy.optimize.linear_sum_assignment`). Matched predicted
  peaks are true positives, the other predicted peaks false positives, the other GT peaks false
  negatives; a peak in the wrong channel is therefore one false positive and one false negative.
  Counts are summed over every view and channel seen; precision, recall and F1 come from the sums.
- **Curvature**: a pixel is positive where the GT curvature exceeds ``curvature_threshold`` (stage 3's
  ``t_b``, with its strict ``>``: :func:`bop_cender.pose.context.scene_context` binarises
  ``curv > t_b``). The average precision of the predicted curvature as a score over all pixels seen,
  from a fixed histogram of ``curvature_bins`` score bins (memory does not grow with the pixels seen),
  and precision, recall and F1 of the prediction binarised as stage 3 does (exact counts, not binned).
  Also the binarisation threshold of the prediction with the best F1 against the same GT pixels (from the
  histogram): a network's curvature is softer than the renderer's, so the ``t_b`` that suits the GT maps
  need not suit its predictions (``poses.network.t_b``).

Ratios with an empty denominator (``0 / 0``) are 1: precision is 1 when nothing was predicted (no false
claim), recall is 1 when there was nothing to find (nothing missed), and F1 is 1 only when there was
neither (``2 tp / (2 tp + fp + fn)`` otherwise, so 0 when one side is empty and the other not).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment

from bop_cender.centers import CenterConfig, find_peaks
from bop_cender.geometry.check import check_shape
from bop_cender.net.heatmaps import Heatmaps
from bop_cender.pose.config import PoseConfig

_STAGE2 = CenterConfig()
_STAGE3 = PoseConfig()


@dataclass(frozen=True)
class HeatmapMetricsConfig:
    """How predicted heatmaps are scored.

    Attributes:
        peak_threshold: minimum value of a predicted center peak; default stage 2's
            (``CenterConfig.peak_threshold``, 0.15), so the figures count the peaks stage 2 triangulates.
        peak_min_distance: ``peak_local_max``'s ``min_distance`` (pixels) for predicted and GT peaks;
            default stage 2's (``CenterConfig.peak_min_distance``, 2).
        pixel_tolerance: a predicted peak at most this many pixels (Euclidean, between pixel centres)
            from a GT peak of the same view and channel can be its true positive.
        gt_peak_threshold: GT peaks are local maxima of the GT center map above this (blobs have peak 1;
            0.5 keeps every blob's top and no tail of a neighbour).
        curvature_threshold: a curvature pixel is positive where its value exceeds this (GT and the
            binarised prediction alike); default stage 3's ``PoseConfig.t_b`` (0.75).
        curvature_bins: score bins of the curvature AP histogram over [0, 1]; AP is evaluated at the
            thresholds ``k / curvature_bins`` (scores within one bin count as ties).
    """

    peak_threshold: float = _STAGE2.peak_threshold
    peak_min_distance: int = _STAGE2.peak_min_distance
    pixel_tolerance: float = 5.0
    gt_peak_threshold: float = 0.5
    curvature_threshold: float = _STAGE3.t_b
    curvature_bins: int = 1000

    def __post_init__(self) -> None:
        for name in ("peak_threshold", "gt_peak_threshold", "curvature_threshold"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {value}")
        if self.peak_min_distance < 1:
            raise ValueError(f"peak_min_distance must be at least 1, got {self.peak_min_distance}")
        if self.pixel_tolerance < 0:
            raise ValueError(f"pixel_tolerance must be non-negative, got {self.pixel_tolerance}")
        if self.curvature_bins < 2:
            raise ValueError(f"curvature_bins must be at least 2, got {self.curvature_bins}")


def match_peaks(pred_xy: np.ndarray, gt_xy: np.ndarray, tolerance: float) -> int:
    """Number of one-to-one pairs of predicted ``(N, 2)`` and GT ``(M, 2)`` points at most ``tolerance`` apart.

    The maximum number of such pairs (Hungarian assignment on the distance matrix, pairs beyond the
    tolerance costing more than any set of pairs within it); among maximum matchings, the one of smallest
    summed distance (that choice does not change the count).
    """
    if len(pred_xy) == 0 or len(gt_xy) == 0:
        return 0
    dist = np.linalg.norm(pred_xy[:, None, :] - gt_xy[None, :, :], axis=-1)  # (N, M)
    within = dist <= tolerance
    if not within.any():
        return 0
    big = (tolerance + 1.0) * (min(dist.shape) + 1)
    rows, cols = linear_sum_assignment(np.where(within, dist, big))
    return int(within[rows, cols].sum())


def _ratio(num: float, den: float) -> float:
    """``num / den``, 1 when ``den`` is 0 (see the module's note on empty denominators)."""
    return 1.0 if den == 0 else num / den


def _f1(tp: float, fp: float, fn: float) -> float:
    """``2 tp / (2 tp + fp + fn)``, 1 when all three are 0."""
    return _ratio(2.0 * tp, 2.0 * tp + fp + fn)


def _probabilities(x: torch.Tensor | np.ndarray, name: str, device: torch.device | None) -> torch.Tensor:
    """``x`` as a float tensor (on ``device`` when given), checked to lie in [0, 1] (not logits)."""
    t = torch.as_tensor(x).detach()
    if device is not None:
        t = t.to(device)
    t = t.float() if not t.is_floating_point() else t
    if t.numel():
        lo, hi = torch.aminmax(t)
        if not (float(lo) >= 0.0 and float(hi) <= 1.0):
            raise ValueError(f"{name}: values must be probabilities in [0, 1], got [{float(lo):g}, {float(hi):g}]")
    return t


@dataclass(eq=False)
class HeatmapMetrics:
    """Stage-1 validation figures accumulated over every view passed to :meth:`update`.

    ``update`` once per batch, ``result`` for the figures of all views seen so far, ``reset`` to start
    again. Inputs may live on any device; the curvature histogram is computed there, the center peaks
    on the CPU (``peak_local_max`` is NumPy).
    """

    config: HeatmapMetricsConfig = field(default_factory=HeatmapMetricsConfig)
    n_views: int = field(default=0, init=False)
    center_tp: int = field(default=0, init=False)
    center_fp: int = field(default=0, init=False)
    center_fn: int = field(default=0, init=False)
    curvature_tp: int = field(default=0, init=False)
    curvature_fp: int = field(default=0, init=False)
    curvature_fn: int = field(default=0, init=False)
    #: ``(2, curvature_bins)`` int64 pixel counts per score bin: row 0 GT-negative, row 1 GT-positive.
    curvature_histogram: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget every view seen."""
        self.n_views = 0
        self.center_tp = self.center_fp = self.center_fn = 0
        self.curvature_tp = self.curvature_fp = self.curvature_fn = 0
        self.curvature_histogram = np.zeros((2, self.config.curvature_bins), dtype=np.int64)

    def update(
        self,
        center_pred: torch.Tensor | np.ndarray,
        curvature_pred: torch.Tensor | np.ndarray,
        center_gt: torch.Tensor | np.ndarray,
        curvature_gt: torch.Tensor | np.ndarray,
    ) -> None:
        """Add a batch of ``B`` views.

        Args:
            center_pred: ``(B, C, H, W)`` predicted center probabilities in [0, 1].
            curvature_pred: ``(B, H, W)`` predicted curvature in [0, 1].
            center_gt: ``(B, C, H, W)`` GT center heatmaps (blobs of peak 1).
            curvature_gt: ``(B, H, W)`` GT curvature in [0, 1].

        GT tensors are moved to the device of the predictions.

        Raises:
            ValueError: a shape that does not match the others (naming the argument), or values outside
                [0, 1] (logits instead of probabilities, say).
        """
        sizes: dict[str, int] = {}
        check_shape(center_pred, "B C H W", "center_pred", sizes)
        check_shape(curvature_pred, "B H W", "curvature_pred", sizes)
        check_shape(center_gt, "B C H W", "center_gt", sizes)
        check_shape(curvature_gt, "B H W", "curvature_gt", sizes)
        cp = _probabilities(center_pred, "center_pred", None)
        kp = _probabilities(curvature_pred, "curvature_pred", cp.device)
        cg = _probabilities(center_gt, "center_gt", cp.device)
        kg = _probabilities(curvature_gt, "curvature_gt", cp.device)
        self._update_centers(cp, cg)
        self._update_curvature(kp, kg)
        self.n_views += sizes["B"]

    def update_heatmaps(self, pred: Heatmaps, gt: Heatmaps) -> None:
        """:meth:`update` with the views of a predicted and a GT :class:`Heatmaps` of the same scene.

        Raises:
            ValueError: the two assign different object ids to the center channels, or shapes differ.
        """
        if pred.channel_obj_ids != gt.channel_obj_ids:
            raise ValueError(f"pred: center channels {pred.channel_obj_ids} differ from gt's {gt.channel_obj_ids}")
        self.update(pred.center, pred.curvature, gt.center, gt.curvature)

    def _update_centers(self, pred: torch.Tensor, gt: torch.Tensor) -> None:
        """Peaks and matches of every view and channel of ``pred`` and ``gt`` ``(B, C, H, W)``."""
        cfg = self.config
        # A map whose maximum does not exceed the threshold has no peak: skip it (most channels of a
        # per-object layout are empty in a view), deciding for the whole batch in one reduction.
        pred_any = (pred.amax(dim=(2, 3)) > cfg.peak_threshold).cpu().numpy()
        gt_any = (gt.amax(dim=(2, 3)) > cfg.gt_peak_threshold).cpu().numpy()
        busy = pred_any | gt_any
        if not busy.any():
            return
        pred_np = pred.cpu().numpy()
        gt_np = gt.cpu().numpy()
        none = np.zeros((0, 2))
        for b, c in zip(*np.nonzero(busy), strict=True):
            p_xy = find_peaks(pred_np[b, c], cfg.peak_threshold, cfg.peak_min_distance)[0] if pred_any[b, c] else none
            g_xy = find_peaks(gt_np[b, c], cfg.gt_peak_threshold, cfg.peak_min_distance)[0] if gt_any[b, c] else none
            tp = match_peaks(p_xy, g_xy, cfg.pixel_tolerance)
            self.center_tp += tp
            self.center_fp += len(p_xy) - tp
            self.center_fn += len(g_xy) - tp

    def _update_curvature(self, pred: torch.Tensor, gt: torch.Tensor) -> None:
        """Histogram and binarised counts of ``pred`` and ``gt`` ``(B, H, W)``."""
        t = self.config.curvature_threshold
        n = self.config.curvature_bins
        positive = gt > t
        # Right-closed bins: bin k holds scores in (k / n, (k + 1) / n], bin 0 also 0 itself, so that
        # "score > k / n" is "bin >= k", the strict comparison of stage 3.
        bins = (torch.ceil(pred * n).long() - 1).clamp_(0, n - 1)
        counts = torch.bincount((bins + n * positive.long()).flatten(), minlength=2 * n)
        self.curvature_histogram += counts.view(2, n).cpu().numpy()
        predicted = pred > t
        self.curvature_tp += int((predicted & positive).sum())
        self.curvature_fp += int((predicted & ~positive).sum())
        self.curvature_fn += int((~predicted & positive).sum())

    def curvature_pr_curve(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Precision-recall curve of the curvature scores of every pixel seen.

        Returns:
            ``thresholds (K,)``: ``k / curvature_bins`` for ``k = K - 1 .. 0`` (descending, ``K`` the bin
            count); ``precision (K,)`` and ``recall (K,)`` of the pixels scoring above each threshold
            (at the last one, 0, every pixel: bin 0 also holds the score 0). Empty denominators give 1.
            The point at ``curvature_threshold`` (when it is a multiple of ``1 / curvature_bins``) is
            the binarised prediction's.
        """
        n = self.config.curvature_bins
        neg, pos = self.curvature_histogram
        tp = np.cumsum(pos[::-1])  # pixels in bins >= k, k from the top down
        fp = np.cumsum(neg[::-1])
        n_pos = tp[-1]
        recall = tp / n_pos if n_pos else np.ones(n)
        predicted = tp + fp
        precision = np.divide(tp, predicted, out=np.ones(n), where=predicted > 0)
        return np.arange(n - 1, -1, -1) / n, precision, recall

    def curvature_ap(self) -> float:
        """Step-wise average precision of the curvature scores of every pixel seen.

        With the thresholds of :meth:`curvature_pr_curve` from the highest down,
        ``AP = sum_k (R_k - R_{k+1}) P_k`` (``R`` recall, ``P`` precision of the pixels above threshold
        ``k``; ``R`` above the highest is 0). With no positive pixel the ranking has nothing to find:
        AP is then the binarised precision (1 when no pixel is predicted above the threshold either, 0
        otherwise).
        """
        if int(self.curvature_histogram[1].sum()) == 0:
            return _ratio(self.curvature_tp, self.curvature_tp + self.curvature_fp)
        _, precision, recall = self.curvature_pr_curve()
        return float(np.sum(np.diff(recall, prepend=0.0) * precision))

    def curvature_best_threshold(self) -> tuple[float, float] | None:
        """The binarisation threshold of the predicted curvature with the best F1 against the GT pixels (the GT
        binarised at ``curvature_threshold``), and that F1: ``(threshold, f1)``.

        A pixel counts as predicted where its score exceeds the threshold, as stage 3 binarises; thresholds are
        the bin edges ``k / curvature_bins``. Ties keep the highest threshold. With no GT-positive pixel:
        None: nothing to calibrate on (no GT-positive pixel).
        """
        if int(self.curvature_histogram[1].sum()) == 0:
            return None
        thresholds, precision, recall = self.curvature_pr_curve()
        denom = precision + recall
        f1 = np.divide(2.0 * precision * recall, denom, out=np.zeros_like(denom), where=denom > 0)
        best = int(np.argmax(f1))  # thresholds descend: the first maximum is the highest threshold
        return float(thresholds[best]), float(f1[best])

    def result(self) -> dict[str, float]:
        """The figures of every view seen.

        Returns:
            ``center_precision``, ``center_recall``, ``center_f1`` (from the summed counts),
            ``center_tp``, ``center_fp``, ``center_fn`` (peak counts), ``curvature_ap``,
            ``curvature_precision``, ``curvature_recall``, ``curvature_f1`` (pixels, binarised at
            ``curvature_threshold``), ``curvature_best_threshold`` and ``curvature_best_f1``
            (:meth:`curvature_best_threshold`; absent without GT-positive pixels) and ``n_views``; counts as floats. Empty denominators give 1 (see
            the module's docstring), so every value is defined, before any update too.
        """
        tp, fp, fn = self.center_tp, self.center_fp, self.center_fn
        ktp, kfp, kfn = self.curvature_tp, self.curvature_fp, self.curvature_fn
        best = self.curvature_best_threshold()
        calibration = {} if best is None else {"curvature_best_threshold": best[0], "curvature_best_f1": best[1]}
        return {
            "center_precision": _ratio(tp, tp + fp),
            "center_recall": _ratio(tp, tp + fn),
            "center_f1": _f1(tp, fp, fn),
            "center_tp": float(tp),
            "center_fp": float(fp),
            "center_fn": float(fn),
            "curvature_ap": self.curvature_ap(),
            "curvature_f1": _f1(ktp, kfp, kfn),
            "curvature_precision": _ratio(ktp, ktp + kfp),
            "curvature_recall": _ratio(ktp, ktp + kfn),
            **calibration,
            "n_views": float(self.n_views),
        }
