"""Tests for bop_cender.eval.matching: top-n cut, valid GTs, greedy matching, recall, AR, toolkit numbers."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from bop_cender.eval.matching import (
    MSPD_THRESHOLDS,
    MSSD_THRESHOLDS,
    VSD_THRESHOLDS,
    EstimateErrors,
    GtInstance,
    Target,
    bop19_scores,
    match,
    normalize_by_diameter,
    normalize_by_image_width,
    recall,
    select_top_n,
    valid_gts,
)

FIXTURE = Path(__file__).parent / "fixtures" / "toolkit_reference.json"


@dataclass
class Est:
    scene_id: int
    im_id: int
    obj_id: int
    score: float
    name: str = ""


def gt(gt_id: int, obj_id: int = 1, visib: float = 1.0, scene_id: int = 1, im_id: int = 0) -> GtInstance:
    return GtInstance(scene_id, im_id, gt_id, obj_id, visib)


def est(est_id: int, score: float, errors: dict, obj_id: int = 1, scene_id: int = 1, im_id: int = 0) -> EstimateErrors:
    return EstimateErrors(scene_id, im_id, obj_id, est_id, score, errors)


def matched(m, th_index: int = 0, variant: int = 0) -> dict[int, int]:
    """gt_id -> est_id of the matches at one threshold."""
    return {
        g.gt_id: int(m.est_ids[variant, th_index, j])
        for j, g in enumerate(m.gts)
        if m.est_ids[variant, th_index, j] >= 0
    }


def test_threshold_constants():
    assert VSD_THRESHOLDS[2] == 0.15000000000000002 and MSSD_THRESHOLDS[2] == 0.15000000000000002
    assert MSPD_THRESHOLDS.tolist() == [5, 10, 15, 20, 25, 30, 35, 40, 45, 50]


# ------------------------------------------------------------------------------------------ top-n


def test_top_n_stable_ties_keep_file_order_and_non_targets_are_ignored():
    ests = [
        Est(1, 0, 1, 0.5, "a"),
        Est(1, 0, 2, 0.99, "other object"),
        Est(1, 0, 1, 0.9, "b"),
        Est(1, 0, 1, 0.5, "c"),
        Est(1, 5, 1, 0.99, "other image"),
        Est(1, 0, 1, 0.5, "d"),
    ]
    targets = [Target(1, 0, 1, inst_count=3)]
    kept = select_top_n(ests, targets)
    assert [(k.estimate.name, k.est_id) for k in kept] == [("b", 1), ("a", 0), ("c", 2)]
    assert [k.estimate.name for k in select_top_n(ests, targets, n_top=0)] == ["b", "a", "c", "d"]
    assert [k.estimate.name for k in select_top_n(ests, targets, n_top=1)] == ["b"]
    assert select_top_n(ests, [Target(2, 0, 1, 1)]) == []  # no estimates for that target


def test_more_estimates_than_gts():
    ests = [Est(1, 0, 1, s) for s in (0.3, 0.8, 0.6)]
    kept = select_top_n(ests, [Target(1, 0, 1, inst_count=1)])
    assert [(k.est_id, k.estimate.score) for k in kept] == [(1, 0.8)]


# ------------------------------------------------------------------------------------------ valid GTs


def test_valid_gts_most_visible_first_ties_by_gt_id():
    gts = [gt(0, 1, 0.5), gt(1, 1, 0.9), gt(2, 1, 0.5), gt(3, 2, 0.05), gt(4, 3, 1.0), gt(0, 1, 1.0, im_id=7)]
    targets = [Target(1, 0, 1, inst_count=2), Target(1, 0, 2, inst_count=1)]
    assert [g.gt_id for g in valid_gts(gts, targets)] == [0, 1, 3]  # obj 1: gt 1 then the tie 0 before 2
    # visib_gt_min >= 0: every target-object instance at least that visible
    assert [g.gt_id for g in valid_gts(gts, targets, visib_gt_min=0.1)] == [0, 1, 2]
    # input order does not matter
    assert [g.gt_id for g in valid_gts(gts[::-1], targets)] == [0, 1, 3]


# ------------------------------------------------------------------------------------------ matching


def test_duplicates_match_only_one_gt():
    valid = [gt(0), gt(1)]
    ests = [est(0, 0.9, {0: 0.01, 1: 0.9}), est(1, 0.8, {0: 0.02, 1: 0.8})]
    m = match(ests, valid, [0.05])
    assert matched(m) == {0: 0}
    assert recall(m).tolist() == [[0.5]] and recall(m, n_targets=4).tolist() == [[0.25]]


def test_greedy_in_score_order_takes_the_lowest_error():
    valid = [gt(0), gt(1)]
    ests = [est(0, 0.7, {0: 0.03, 1: 0.001}), est(1, 0.9, {0: 0.02, 1: 0.01})]
    m = match(ests, valid, [0.05, 0.025])
    assert matched(m, 0) == {1: 1, 0: 0}  # est 1 first takes gt 1 (0.01); est 0 then gets gt 0 (0.03)
    assert matched(m, 1) == {1: 1}  # at 0.025, gt 0's 0.03 is too far for est 0
    assert m.errors[0, 0, 0] == 0.03 and np.isnan(m.errors[0, 1, 0])


def test_score_ties_go_in_est_id_order_and_error_ties_to_the_lowest_gt_id():
    valid = [gt(0), gt(1)]
    ests = [est(1, 0.5, {0: 0.01, 1: 0.01}), est(0, 0.5, {0: 0.01, 1: 0.01})]
    assert matched(match(ests, valid, [0.05])) == {0: 0, 1: 1}


def test_threshold_equality_is_not_correct_but_arange_noise_is():
    valid = [gt(0), gt(1), gt(2)]
    ests = [est(0, 0.9, {0: 0.05}), est(1, 0.8, {1: 0.15}), est(2, 0.7, {2: 0.15000000000000002})]
    m = match(ests, valid, MSSD_THRESHOLDS)
    assert matched(m, 0) == {}  # 0.05 < 0.05 is False
    assert matched(m, 2) == {0: 0, 1: 1}  # 0.15 < 0.15000000000000002, but that value itself is not
    assert matched(m, 3) == {0: 0, 1: 1, 2: 2}


def test_invalid_and_non_target_gts_never_match():
    valid = [gt(0)]
    ests = [
        est(0, 0.9, {1: 0.0}),  # gt 1 is not valid
        est(0, 0.9, {0: 0.0}, im_id=3),  # another image: its gt 0 is not valid
        est(1, 0.5, {0: np.inf, 1: np.nan}),
    ]
    m = match(ests, valid, [0.1])
    assert matched(m) == {} and recall(m).tolist() == [[0.0]]


def test_vsd_variants_and_thresholds_are_independent():
    valid = [gt(0)]
    e = est(0, 0.9, {0: np.array([0.5, 0.2, 0.05])})
    m = match([e], valid, [0.1, 0.3])
    assert m.est_ids.shape == (3, 2, 1)
    assert (m.est_ids[:, :, 0] >= 0).tolist() == [[False, False], [False, True], [True, True]]
    with pytest.raises(ValueError, match="variants"):
        match([e, est(1, 0.1, {0: 0.1})], valid, [0.1])


def test_recall_is_pooled_over_images_and_zero_without_gts():
    valid = [gt(0), gt(1), gt(0, im_id=1), gt(0, scene_id=2)]
    ests = [est(0, 1.0, {0: 0.0}), est(0, 1.0, {0: 0.0}, im_id=1), est(0, 1.0, {0: 0.9}, scene_id=2)]
    m = match(ests, valid, [0.5])
    assert recall(m).tolist() == [[0.5]]
    assert recall(match([], [], [0.1, 0.2])).tolist() == [[0.0, 0.0]]


# ------------------------------------------------------------------------------------------ AR


def test_average_recalls():
    vsd_r = np.linspace(0.0, 0.99, 100).reshape(10, 10)
    mssd_r = np.linspace(0.1, 1.0, 10)[None]  # recall() gives a leading variant axis
    mspd_r = np.linspace(0.2, 0.65, 10)
    ar = bop19_scores(vsd_r, mssd_r, mspd_r)
    assert ar["AR_VSD"] == pytest.approx(0.495) and ar["AR_MSSD"] == pytest.approx(0.55)
    assert ar["AR_MSPD"] == pytest.approx(0.425) and ar["AR"] == pytest.approx((0.495 + 0.55 + 0.425) / 3)
    assert ar["AR_MSPD<5px"] == 0.2 and ar["AR_MSSD<5%"] == pytest.approx(0.1)
    no_depth = bop19_scores(None, mssd_r, mspd_r)
    assert no_depth["AR"] is None and no_depth["AR_VSD"] is None and no_depth["AR_MSSD"] == ar["AR_MSSD"]


def test_normalisation_in_the_toolkit_order():
    assert normalize_by_image_width(9.0, 720) == (640.0 / 720) * 9.0
    assert normalize_by_diameter(np.array([30.0]), 120) == pytest.approx([0.25])


# ------------------------------------------------------------------------------------------ official numbers


def test_matches_official_toolkit_numbers():
    ref = json.loads(FIXTURE.read_text())["matching"]
    targets = [Target(t["scene_id"], t["im_id"], t["obj_id"], t["inst_count"]) for t in ref["targets"]]
    gts = [GtInstance(*g) for g in ref["gts"]]
    ests = [Est(*e) for e in ref["estimates"]]
    kept = select_top_n(ests, targets)
    assert sorted([k.estimate.scene_id, k.estimate.im_id, k.estimate.obj_id, k.est_id] for k in kept) == sorted(
        ref["kept"]
    )
    valid = valid_gts(gts, targets)
    assert sorted([list(g.key) for g in valid]) == ref["valid"]
    recalls = {}
    for kind, ths in (("mssd", MSSD_THRESHOLDS), ("mspd", MSPD_THRESHOLDS), ("vsd", VSD_THRESHOLDS)):
        errs = [
            EstimateErrors(*row["key"], row["score"], {int(g): np.asarray(v[kind]) for g, v in row["errors"].items()})
            for row in ref["errors"]
        ]
        recalls[kind] = recall(match(errs, valid, ths))
        assert recalls[kind].tolist() == ref["recalls"][kind], kind  # exact
    ar = bop19_scores(recalls["vsd"], recalls["mssd"], recalls["mspd"])
    want = ref["average_recalls"]
    assert (ar["AR_VSD"], ar["AR_MSSD"], ar["AR_MSPD"], ar["AR"]) == (
        want["vsd"],
        want["mssd"],
        want["mspd"],
        want["all"],
    )
    assert 0.0 < ar["AR"] < 1.0
