"""BOP'24 detection rules on plain inputs (bop_cender.eval.detection), each named after the toolkit's rule."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from bop_cender.eval.detection import (
    BOP24_KEYS,
    MSPD_THRESHOLDS,
    MSSD_MM_THRESHOLDS,
    MSSD_THRESHOLDS,
    RECALL_POINTS,
    ErrorTypeScores,
    average_precision,
    cap_per_image,
    detection_scores,
    error_type_scores,
    gt_order,
    interpolated_precisions,
    match_detections,
    max_estimates_per_image,
    time_per_image,
)


@dataclass
class R:
    scene_id: int
    im_id: int
    obj_id: int
    score: float
    time: float = 0.5
    tag: str = ""


def test_thresholds_are_the_toolkits() -> None:
    assert MSSD_THRESHOLDS[2] == 0.15000000000000002  # np.arange's noise, as eval_bop24_pose.py makes them
    assert MSSD_MM_THRESHOLDS.tolist() == [2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 14.0, 16.0, 18.0, 20.0]
    assert MSPD_THRESHOLDS.tolist() == [5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0, 45.0, 50.0]
    assert len(RECALL_POINTS) == 101 and RECALL_POINTS[50] == 0.5
    assert max_estimates_per_image("tless") == 100 and max_estimates_per_image("xyzibd") == 200


def test_cap_keeps_the_best_scored_per_image_and_ties_keep_file_order() -> None:
    rows = [R(1, 0, 1, 0.5, tag="a"), R(1, 0, 2, 0.9, tag="b"), R(1, 1, 1, 0.1, tag="other image"),
            R(1, 0, 3, 0.5, tag="c"), R(1, 0, 1, 0.5, tag="d")]  # fmt: skip
    capped = cap_per_image(rows, 3)
    # image (1, 0): b (0.9) then the 0.5s in file order a, c, d; the cap of 3 cuts d (the later of equal scores)
    assert [r.tag for r in capped.kept] == ["b", "a", "c", "other image"]
    assert [r.tag for r in capped.cut] == ["d"]
    with pytest.raises(ValueError):
        cap_per_image(rows, 0)


def test_cap_counts_rows_of_every_object_even_those_ignored_later() -> None:
    """An object the image does not hold still takes a place under the cap (the toolkit caps before errors)."""
    rows = [R(1, 0, 99, 0.9, tag="unknown object"), R(1, 0, 1, 0.8, tag="a"), R(1, 0, 1, 0.7, tag="b")]
    assert [r.tag for r in cap_per_image(rows, 2).cut] == ["b"]


def test_negative_scores_sort_below_zero() -> None:
    rows = [R(1, 0, 1, -0.5, tag="neg"), R(1, 0, 1, 0.0, tag="zero"), R(1, 0, 1, -0.1, tag="less neg")]
    assert [r.tag for r in cap_per_image(rows, 5).kept] == ["zero", "less neg", "neg"]


def test_gt_ids_are_visited_as_text_like_the_toolkits_json_keys() -> None:
    assert gt_order([2, 10, 1, 11]) == [1, 10, 11, 2]


def test_matching_is_greedy_by_score_strictly_below_the_threshold() -> None:
    errors = np.array([[0.3, 0.1], [0.05, 0.2], [0.2, 0.2]])  # 3 estimates x 2 GTs
    scores = np.array([0.5, 0.9, 0.7])
    taken = match_detections(errors, scores, np.array([0.1, 0.25, 0.5]))
    # threshold 0.1: estimate 1 (score 0.9) takes GT 0 (0.05); 0.1 is not below 0.1, so nothing else matches
    assert taken[:, 0].tolist() == [-1, 0, -1]
    # 0.25: estimate 1 takes GT 0, estimate 2 (0.7) GT 1 (0.2), estimate 0 (0.5) finds both taken
    assert taken[:, 1].tolist() == [-1, 0, 1]
    assert taken[:, 2].tolist() == [-1, 0, 1]


def test_equal_scores_go_in_est_id_order_and_equal_errors_to_the_first_gt() -> None:
    errors = np.array([[0.1, 0.1], [0.1, 0.1]])
    taken = match_detections(errors, np.array([0.5, 0.5]), np.array([0.2]))
    assert taken[:, 0].tolist() == [0, 1]  # estimate 0 first, to the first column (the toolkit's order) on a tie
    assert match_detections(np.zeros((0, 2)), np.zeros(0), np.array([0.2])).shape == (0, 1)


def test_ap_is_the_toolkits_101_point_interpolation() -> None:
    """score.py's own example: tp = F T T F T F over 6 GTs; precision 2/3 up to recall 1/3, 0.6 up to 1/2, then 0."""
    curve = average_precision(np.array([False, True, True, False, True, False]), 6)
    assert curve.ap == pytest.approx((34 * 2 / 3 + 17 * 0.6) / 101, abs=1e-15)
    assert (curve.true_positives, curve.false_positives, curve.n_gts) == (3, 3, 6)
    assert curve.precisions[0] == pytest.approx(2 / 3) and curve.precisions[50] == pytest.approx(0.6)
    assert curve.precisions[51] == 0.0


def test_ap_of_no_estimate_is_zero_and_perfect_estimates_give_one() -> None:
    assert average_precision(np.zeros(0, dtype=bool), 3).ap == 0.0
    assert average_precision(np.array([True, True, True]), 3).ap == 1.0
    assert average_precision(np.array([True, True, True, False]), 3).ap == 1.0  # a false positive ranked last
    assert average_precision(np.array([False, True, True, True]), 3).ap < 1.0  # ... ranked first costs


def test_interpolated_precision_is_the_best_at_any_higher_recall() -> None:
    rec = np.array([0.2, 0.2, 0.6, 1.0])
    pre = np.array([1.0, 0.5, 0.75, 0.4])
    out = interpolated_precisions(rec, pre)
    brute = [max(p for r, p in zip([0.0, *rec, 1.0], [0.0, *pre, 0.0], strict=True) if r >= t) for t in RECALL_POINTS]
    assert out.tolist() == brute


def test_estimates_matched_to_hidden_instances_are_left_out_and_hidden_instances_not_counted() -> None:
    obj_ids = np.array([1, 1, 1, 2])
    scores = np.array([0.9, 0.8, 0.7, 0.5])
    status = np.array([[1], [-1], [0], [1]], dtype=np.int8)  # TP, left out (hidden GT), FP; object 2 TP
    s = error_type_scores(obj_ids, scores, status, {1: 1, 2: 1, 3: 0}, np.array([0.5]))
    assert s.objects == (1, 2)  # object 3 has no instance >= 10 % visible: not in the mean
    assert s.curves[1][0].true_positives == 1 and s.curves[1][0].false_positives == 1  # the left-out one not counted
    assert s.object_ap[1] == 1.0  # the FP comes after the only GT is found
    assert s.mean_ap == 1.0


def test_ties_in_score_keep_the_evaluated_order() -> None:
    """Equal scores across images: the evaluated order decides which comes first in the curve (a stable sort)."""
    status_fp_first = np.array([[0], [1]], dtype=np.int8)
    s = error_type_scores(np.array([1, 1]), np.array([0.5, 0.5]), status_fp_first, {1: 1}, np.array([0.5]))
    assert s.object_ap[1] == pytest.approx(0.5)  # FP then TP: precision 1/2 at recall 1


def test_keys_and_unknown_time() -> None:
    per_type = {
        name: ErrorTypeScores(ap, np.array([0.5]), (1,), {1: ap}, {})
        for name, ap in (("mssd", 0.4), ("mssd_mm", 0.2), ("mspd", 0.6))
    }
    scores = detection_scores(per_type, None)
    assert tuple(scores) == BOP24_KEYS
    assert scores["bop24_mAP"] == pytest.approx(0.5) and scores["bop25_mAP"] == 0.4 and scores["bop25_mAP_mm"] == 0.2
    assert scores["bop24_average_time_per_image"] == -1.0  # the toolkit's value for an unknown time
    assert detection_scores(per_type, 0.25)["bop24_average_time_per_image"] == 0.25


def test_time_per_image_skips_unknown_times_and_reports_inconsistent_ones() -> None:
    assert time_per_image([R(1, 0, 1, 0.5, 0.2), R(1, 1, 1, 0.5, 0.4)]) == (pytest.approx(0.3), [])
    assert time_per_image([R(1, 0, 1, 0.5, 0.2), R(1, 0, 1, 0.4, -1)])[0] is None  # one unknown: unknown
    mean, problems = time_per_image([R(1, 0, 1, 0.5, 0.2), R(1, 0, 1, 0.4, 0.3)])
    assert len(problems) == 1 and "scene 1 image 0" in problems[0]
