"""Stage-1 validation figures: center peaks matched within a tolerance per channel, curvature AP and F1."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from bop_cender.centers import CenterConfig
from bop_cender.net.heatmaps import Heatmaps
from bop_cender.net.metrics import HeatmapMetrics, HeatmapMetricsConfig, match_peaks
from bop_cender.pose.config import PoseConfig

H, W = 48, 64


def blobs(*centres: tuple[float, float], peak: float = 1.0, sigma: float = 2.5) -> torch.Tensor:
    """``(H, W)`` max of Gaussian blobs at image points (x, y), evaluated at pixel centres, as the GT targets."""
    u = torch.arange(W, dtype=torch.float32) + 0.5
    v = torch.arange(H, dtype=torch.float32) + 0.5
    out = torch.zeros(H, W)
    for x, y in centres:
        g = torch.exp(-((v[:, None] - y) ** 2 + (u[None, :] - x) ** 2) / (2 * sigma**2))
        out = torch.maximum(out, peak * g)
    return out


def maps(*channels: list[tuple[float, float]], **kw) -> torch.Tensor:
    """``(1, C, H, W)``: one view, one channel per list of blob centres."""
    return torch.stack([blobs(*c, **kw) for c in channels])[None]


def flat_curvature(value: float = 0.0) -> torch.Tensor:
    return torch.full((1, H, W), value)


def center_figures(pred: torch.Tensor, gt: torch.Tensor, **config) -> dict[str, float]:
    m = HeatmapMetrics(HeatmapMetricsConfig(**config))
    curv = flat_curvature().expand(pred.shape[0], H, W)
    m.update(pred, curv, gt, curv)
    return m.result()


def counts(r: dict[str, float]) -> tuple[float, float, float]:
    return r["center_tp"], r["center_fp"], r["center_fn"]


def exact_ap(scores: np.ndarray, positive: np.ndarray) -> float:
    """Reference step-wise AP over every distinct score (ties one threshold), without a histogram."""
    order = np.argsort(-scores, kind="stable")
    s, p = scores[order], positive[order]
    tp, fp = np.cumsum(p), np.cumsum(~p)
    last = np.r_[np.nonzero(np.diff(s))[0], len(s) - 1]  # the end of each run of equal scores
    recall = tp[last] / p.sum()
    precision = tp[last] / (tp[last] + fp[last])
    return float(np.sum(np.diff(recall, prepend=0.0) * precision))


def curvature_scene(seed: int = 0, views: int = 4) -> tuple[torch.Tensor, torch.Tensor]:
    """GT curvature with edges (1.0), curved surfaces (0.5) and background (0), and a noisy prediction."""
    g = torch.Generator().manual_seed(seed)
    gt = torch.zeros(views, H, W)
    gt[:, 10:12, 5:50] = 1.0
    gt[:, 20:30, 20:40] = 0.5
    gt[:, 20:30, 19] = 1.0
    pred = (gt * 0.8 + 0.3 * torch.rand(views, H, W, generator=g)).clamp(0, 1)
    return pred, gt


def test_defaults_are_those_of_stages_2_and_3():
    cfg = HeatmapMetricsConfig()
    assert cfg.peak_threshold == CenterConfig().peak_threshold == 0.15
    assert cfg.peak_min_distance == CenterConfig().peak_min_distance == 2
    assert cfg.curvature_threshold == PoseConfig().t_b == 0.75
    assert (cfg.pixel_tolerance, cfg.gt_peak_threshold) == (5.0, 0.5)


def test_perfect_prediction_scores_one():
    center = torch.cat([maps([(10.5, 10.5), (40.2, 30.7)], [(25.0, 20.0)]), maps([(5.5, 40.5)], [])])
    _, curv = curvature_scene(views=2)
    m = HeatmapMetrics()
    m.update(center, curv, center, curv)
    r = m.result()
    assert counts(r) == (4.0, 0.0, 0.0)
    for key in ("center_precision", "center_recall", "center_f1", "curvature_ap", "curvature_f1"):
        assert r[key] == 1.0, key
    assert r["curvature_precision"] == r["curvature_recall"] == 1.0
    assert r["n_views"] == 2.0


@pytest.mark.parametrize(("shift", "expected"), [(3.0, (1, 0, 0)), (4.9, (1, 0, 0)), (8.0, (0, 1, 1))])
def test_a_shifted_blob_is_a_hit_within_the_tolerance_and_a_miss_beyond(shift, expected):
    gt = maps([(20.5, 20.5)])
    pred = maps([(20.5 + shift, 20.5)])
    assert counts(center_figures(pred, gt)) == expected


def test_an_extra_blob_is_a_false_positive_and_a_missing_one_a_false_negative():
    gt = maps([(10.5, 10.5), (40.5, 30.5)])
    extra = center_figures(maps([(10.5, 10.5), (40.5, 30.5), (55.5, 8.5)]), gt)
    assert counts(extra) == (2, 1, 0)
    assert extra["center_precision"] == pytest.approx(2 / 3) and extra["center_recall"] == 1.0
    assert extra["center_f1"] == pytest.approx(0.8)
    missing = center_figures(maps([(40.5, 30.5)]), gt)
    assert counts(missing) == (1, 0, 1)
    assert missing["center_precision"] == 1.0 and missing["center_recall"] == 0.5


def test_a_blob_in_the_wrong_channel_is_a_false_positive_and_a_false_negative():
    gt = maps([(20.5, 20.5)], [])
    pred = maps([], [(20.5, 20.5)])
    assert counts(center_figures(pred, gt)) == (0, 1, 1)


def test_predicted_peaks_use_stage_2_threshold():
    gt = maps([(20.5, 20.5)])
    assert counts(center_figures(maps([(20.5, 20.5)], peak=0.1), gt)) == (0, 0, 1)
    assert counts(center_figures(maps([(20.5, 20.5)], peak=0.2), gt)) == (1, 0, 0)


def test_matching_is_one_to_one_and_finds_the_most_pairs():
    # Greedy by distance would pair (4, 0)-(3, 0) first and leave (0, 0) and (7.5, 0) 7.5 apart: 1 pair.
    pred = np.array([[0.0, 0.0], [4.0, 0.0]])
    gt = np.array([[3.0, 0.0], [7.5, 0.0]])
    assert match_peaks(pred, gt, 5.0) == 2
    assert match_peaks(pred[:1], np.array([[1.0, 0.0], [2.0, 0.0]]), 5.0) == 1
    assert match_peaks(pred, np.zeros((0, 2)), 5.0) == 0
    # two predicted blobs close to one GT blob: one hit, one false positive
    r = center_figures(maps([(20.5, 20.5), (25.5, 20.5)]), maps([(22.5, 20.5)]))
    assert counts(r) == (1, 1, 0)


def test_empty_maps_give_defined_values():
    r = HeatmapMetrics().result()  # before any update
    assert all(math.isfinite(v) for v in r.values())
    assert r["center_f1"] == r["curvature_ap"] == r["curvature_f1"] == 1.0 and r["n_views"] == 0
    nothing = center_figures(maps([]), maps([]))
    assert counts(nothing) == (0, 0, 0)
    assert nothing["center_precision"] == nothing["center_recall"] == nothing["center_f1"] == 1.0
    assert nothing["curvature_ap"] == nothing["curvature_f1"] == 1.0
    only_gt = center_figures(maps([]), maps([(20.5, 20.5)]))
    assert (only_gt["center_precision"], only_gt["center_recall"], only_gt["center_f1"]) == (1.0, 0.0, 0.0)
    only_pred = center_figures(maps([(20.5, 20.5)]), maps([]))
    assert (only_pred["center_precision"], only_pred["center_recall"], only_pred["center_f1"]) == (0.0, 1.0, 0.0)
    # curvature predicted where the GT has none: nothing to find, everything claimed wrongly
    m = HeatmapMetrics()
    m.update(maps([]), flat_curvature(0.9), maps([]), flat_curvature(0.0))
    r = m.result()
    assert (r["curvature_ap"], r["curvature_precision"], r["curvature_recall"], r["curvature_f1"]) == (0, 0, 1, 0)


def test_curvature_threshold_is_strict_as_in_stage_3():
    gt = flat_curvature(0.0)
    gt[0, :2] = 1.0
    gt[0, 2:5] = 0.75  # not above t_b = 0.75: negative
    m = HeatmapMetrics()
    m.update(maps([]), torch.full((1, H, W), 0.75), maps([]), gt)  # nothing predicted above t_b either
    r = m.result()
    assert (m.curvature_tp, m.curvature_fp, m.curvature_fn) == (0, 0, 2 * W)
    assert r["curvature_recall"] == 0.0 and r["curvature_precision"] == 1.0


def test_the_pr_curve_passes_through_the_binarised_prediction():
    g = torch.Generator().manual_seed(6)
    gt = (torch.rand(2, H, W, generator=g) < 0.3).float()
    levels = torch.tensor([0.0, 0.5, 0.74, 0.75, 0.7505, 0.8, 1.0])  # 0.75 exactly: not above t_b
    pred = levels[torch.randint(len(levels), (2, H, W), generator=g)]
    m = HeatmapMetrics()
    m.update(torch.zeros(2, 1, H, W), pred, torch.zeros(2, 1, H, W), gt)
    thresholds, precision, recall = m.curvature_pr_curve()
    assert thresholds.shape == precision.shape == recall.shape == (1000,)
    assert thresholds[0] == 0.999 and thresholds[-1] == 0.0 and np.all(np.diff(thresholds) < 0)
    at = int(np.nonzero(np.isclose(thresholds, 0.75))[0][0])
    r = m.result()
    assert (precision[at], recall[at]) == pytest.approx((r["curvature_precision"], r["curvature_recall"]), abs=1e-12)
    assert recall[-1] == 1.0 and precision[-1] == pytest.approx(float(gt.mean()))
    assert r["curvature_ap"] == pytest.approx(exact_ap(pred.flatten().numpy(), gt.flatten().numpy() > 0.75), abs=1e-12)


def test_curvature_ap_of_a_random_prediction_is_the_positive_rate():
    g = torch.Generator().manual_seed(1)
    gt = (torch.rand(8, H, W, generator=g) < 0.2).float()
    pred = torch.rand(8, H, W, generator=g)
    m = HeatmapMetrics()
    m.update(torch.zeros(8, 1, H, W), pred, torch.zeros(8, 1, H, W), gt)
    rate = float(gt.mean())
    assert m.result()["curvature_ap"] == pytest.approx(rate, abs=0.015)


def test_curvature_ap_matches_the_exact_definition_and_ignores_monotone_transforms():
    g = torch.Generator().manual_seed(2)
    gt = (torch.rand(4, H, W, generator=g) < 0.3).float()
    # scores on 20 levels, correlated with the GT: every level in a bin of its own, so the histogram is exact
    level = (gt * 6 + torch.rand(4, H, W, generator=g) * 14).floor().clamp(0, 19)
    scores = (level + 0.5) / 20
    aps = []
    for transform in (lambda s: s, torch.sqrt, lambda s: s**3, lambda s: 0.1 + 0.8 * s):
        m = HeatmapMetrics()
        m.update(torch.zeros(4, 1, H, W), transform(scores), torch.zeros(4, 1, H, W), gt)
        aps.append(m.result()["curvature_ap"])
    reference = exact_ap(scores.flatten().numpy(), gt.flatten().numpy() > 0.75)
    assert 0.3 < reference < 0.99
    assert aps == pytest.approx([reference] * 4, abs=1e-12)
    # continuous scores: the 1000 bins tie a few near neighbours only
    pred, curv = curvature_scene(seed=3)
    m1, m2 = HeatmapMetrics(), HeatmapMetrics()
    m1.update(torch.zeros(4, 1, H, W), pred, torch.zeros(4, 1, H, W), curv)
    m2.update(torch.zeros(4, 1, H, W), pred.sqrt(), torch.zeros(4, 1, H, W), curv)
    ref = exact_ap(pred.flatten().numpy(), curv.flatten().numpy() > 0.75)
    assert m1.result()["curvature_ap"] == pytest.approx(ref, abs=2e-3)
    assert m2.result()["curvature_ap"] == pytest.approx(ref, abs=2e-3)


def test_two_updates_equal_one_on_the_concatenated_batch():
    center_pred = torch.cat([maps([(10.5, 10.5), (30.0, 30.0)], [(50.5, 12.5)]), maps([(12.5, 40.5)], [])])
    center_gt = torch.cat([maps([(11.5, 10.5)], [(50.5, 20.5)]), maps([(12.5, 40.5)], [(40.5, 20.5)])])
    curv_pred, curv_gt = curvature_scene(seed=4, views=2)
    whole = HeatmapMetrics()
    whole.update(center_pred, curv_pred, center_gt, curv_gt)
    parts = HeatmapMetrics()
    for i in range(2):
        parts.update(center_pred[i : i + 1], curv_pred[i : i + 1], center_gt[i : i + 1], curv_gt[i : i + 1])
    assert parts.result() == whole.result()
    assert counts(whole.result()) == (2, 2, 2)
    assert whole.result()["n_views"] == 2
    whole.reset()
    assert whole.result() == HeatmapMetrics().result()


def test_heatmaps_are_accepted_and_their_channels_checked():
    center = maps([(20.5, 20.5)], [])
    curv = flat_curvature()
    pred = Heatmaps(center, curv, channel_obj_ids=(1, 2), im_ids=(0,))
    m = HeatmapMetrics()
    m.update_heatmaps(pred, Heatmaps(center, curv, channel_obj_ids=(1, 2), im_ids=(0,)))
    assert counts(m.result()) == (1, 0, 0)
    with pytest.raises(ValueError, match="channels"):
        m.update_heatmaps(pred, Heatmaps(center, curv, channel_obj_ids=(2, 1), im_ids=(0,)))


@pytest.mark.parametrize(
    ("name", "shape"),
    [
        ("center_pred", (1, H, W)),
        ("curvature_pred", (1, 1, H, W)),
        ("center_gt", (1, 2, H, W)),
        ("curvature_gt", (1, H, W + 1)),
        ("curvature_pred", (2, H, W)),
    ],
)
def test_bad_shapes_name_the_argument(name, shape):
    args = {
        "center_pred": torch.zeros(1, 1, H, W),
        "curvature_pred": torch.zeros(1, H, W),
        "center_gt": torch.zeros(1, 1, H, W),
        "curvature_gt": torch.zeros(1, H, W),
    }
    args[name] = torch.zeros(shape)
    with pytest.raises(ValueError, match=name):
        HeatmapMetrics().update(**args)


def test_logits_are_refused():
    with pytest.raises(ValueError, match="curvature_pred.*probabilities"):
        HeatmapMetrics().update(maps([]), flat_curvature(3.0), maps([]), flat_curvature())
    with pytest.raises(ValueError, match="peak_threshold"):
        HeatmapMetricsConfig(peak_threshold=1.5)


def test_results_follow_the_device(device):
    center_pred = torch.cat([maps([(10.5, 10.5), (30.0, 30.0)], [(50.5, 12.5)]), maps([(12.5, 40.5)], [])])
    center_gt = torch.cat([maps([(11.5, 10.5)], [(50.5, 20.5)]), maps([(12.5, 40.5)], [(40.5, 20.5)])])
    curv_pred, curv_gt = curvature_scene(seed=5, views=2)
    cpu = HeatmapMetrics()
    cpu.update(center_pred, curv_pred, center_gt, curv_gt)
    on_device = HeatmapMetrics()
    on_device.update(center_pred.to(device), curv_pred.to(device), center_gt.to(device), curv_gt.to(device))
    assert on_device.result() == cpu.result()


def test_the_best_curvature_threshold_separates_a_soft_prediction_and_is_the_highest_of_ties():
    """A network's edges at 0.6 and its background at 0.3: at t_b (0.75) it finds nothing; the best threshold is
    the highest bin edge under 0.6, where every edge pixel and no other is above it (F1 1)."""
    gt = flat_curvature(0.0)
    gt[0, :3] = 1.0
    pred = torch.where(gt > 0.5, 0.6, 0.3)
    m = HeatmapMetrics()
    m.update(maps([]), pred, maps([]), gt)
    threshold, f1 = m.curvature_best_threshold()
    assert threshold == pytest.approx(0.599) and f1 == pytest.approx(1.0)
    r = m.result()
    assert r["curvature_f1"] == 0.0 and (r["curvature_best_threshold"], r["curvature_best_f1"]) == (threshold, f1)
    # one wrong pixel above the edges' value: the best threshold stays where F1 is best, not at the top
    pred[0, 5, 5] = 0.9
    m = HeatmapMetrics()
    m.update(maps([]), pred, maps([]), gt)
    threshold, f1 = m.curvature_best_threshold()
    assert threshold == pytest.approx(0.599) and f1 == pytest.approx(2 * 3 * W / (2 * 3 * W + 1))


def test_without_curvature_gt_there_is_no_best_threshold():
    """Nothing to calibrate on: no threshold (train then stores none), and the figures leave it out."""
    m = HeatmapMetrics()
    m.update(maps([]), flat_curvature(0.2), maps([]), flat_curvature(0.0))
    assert m.curvature_best_threshold() is None and "curvature_best_threshold" not in m.result()
