"""Tests for bop_cender.eval.vsd: visibility rules, tau boundary, windows, toolkit numbers."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bop_cender.eval.vsd import (
    VSD_TAUS,
    depth_to_distance,
    overlapping_sphere_projections,
    vsd,
    vsd_delta,
)

FIXTURE = Path(__file__).parent / "fixtures" / "toolkit_reference.json"
H, W = 12, 16
# Integer principal point: at pixel (row 6, column 8) the distance equals the depth exactly.
K = np.array([[100.0, 0.0, 8.0], [0.0, 100.0, 6.0], [0.0, 0.0, 1.0]])
CY, CX = 6, 8


def _bounding_window(*depths: np.ndarray) -> tuple[int, int, int, int]:
    """``(y0, x0, y1, x1)`` of the non-zero pixels of the given renders (at least one must have some)."""
    rows, cols = np.nonzero(np.any(np.stack(depths) > 0, axis=0))
    return int(rows.min()), int(cols.min()), int(rows.max()) + 1, int(cols.max()) + 1


def image(value: float = 0.0) -> np.ndarray:
    return np.full((H, W), value, dtype=np.float32)


def test_constants_keep_the_toolkit_float_noise():
    assert len(VSD_TAUS) == 10
    assert VSD_TAUS[2] == 0.15000000000000002 and VSD_TAUS[6] == 0.35000000000000003
    assert VSD_TAUS[0] == 0.05 and VSD_TAUS[-1] == 0.5
    assert vsd_delta("itodd") == 5.0 and vsd_delta("tless") == 15.0 and vsd_delta("dimo") == 15.0


def test_depth_to_distance_uses_integer_pixel_indices():
    depth = image(500.0)
    dist = depth_to_distance(depth, K)
    assert dist[CY, CX] == 500.0
    # column 0: x - cx = -8, no +0.5
    assert dist[CY, 0] == pytest.approx(500.0 * np.sqrt(1.0 + 0.08**2), rel=1e-15)
    assert dist[0, 0] == pytest.approx(500.0 * np.sqrt(1.0 + 0.08**2 + 0.06**2), rel=1e-15)
    depth[3, 4] = 0.0
    assert depth_to_distance(depth, K)[3, 4] == 0.0
    # a crop with its origin gives the same values as the full image
    np.testing.assert_array_equal(
        depth_to_distance(depth[2:7, 3:11], K, origin=(2, 3)), depth_to_distance(depth, K)[2:7, 3:11]
    )


def test_identical_depths_score_zero():
    gt = image()
    gt[4:9, 5:12] = 600.0
    assert np.array_equal(vsd(gt.copy(), gt.copy(), gt.copy(), K, 15.0, VSD_TAUS, 100.0), np.zeros(10))


def test_tau_equality_is_a_miss():
    """One pixel at the principal point: |dist_gt - dist_est| / diameter = 10 / 100 = 0.1 exactly."""
    test, gt, est = image(), image(), image()
    test[CY, CX] = gt[CY, CX] = 500.0
    est[CY, CX] = 510.0
    e = vsd(test, est, gt, K, 15.0, [0.05, 0.1, 0.15000000000000002], 100.0)
    assert e.tolist() == [1.0, 1.0, 0.0]
    # not normalised: tau in mm
    assert vsd(test, est, gt, K, 15.0, [10.0, 10.5], None, normalized_by_diameter=False).tolist() == [1.0, 0.0]


def test_estimate_hidden_behind_the_test_depth_and_missing_test_depth():
    """GT: 2x2 block, visible. Estimate: the same block plus 2 pixels 100 mm behind the scene."""
    test, gt, est = image(500.0), image(), image()
    gt[5:7, 7:9] = 500.0
    est[5:7, 7:9] = 500.0
    est[5:7, 9] = 600.0
    assert vsd(test, est, gt, K, 15.0, VSD_TAUS, 100.0).tolist() == [0.0] * 10  # the 2 pixels are occluded
    test[5:7, 9] = 0.0  # missing test depth counts as visible: union 6, intersection 4
    np.testing.assert_array_equal(vsd(test, est, gt, K, 15.0, VSD_TAUS, 100.0), np.full(10, 2.0 / 6.0))


def test_estimate_visibility_includes_gt_visible_pixels():
    """The estimate lies 20 mm behind a visible GT (beyond delta): it still counts where the GT is visible."""
    test, gt, est = image(500.0), image(), image()
    gt[CY, CX] = 500.0
    est[CY, CX] = 520.0
    e = vsd(test, est, gt, K, 15.0, VSD_TAUS, 1000.0)  # dists 0.02 < every tau
    assert e.tolist() == [0.0] * 10


def test_fully_occluded_gt_gives_one():
    test, gt = image(500.0), image()
    gt[4:8, 4:8] = 700.0  # far behind the scene: no visible GT pixel
    assert vsd(test, gt.copy(), gt, K, 15.0, VSD_TAUS, 100.0).tolist() == [1.0] * 10  # |union| = 0
    est = image()
    est[4:8, 9:12] = 505.0  # the estimate is visible elsewhere: union > 0, intersection empty
    assert vsd(test, est, gt, K, 15.0, VSD_TAUS, 100.0).tolist() == [1.0] * 10
    assert vsd(test, image(), image(), K, 15.0, VSD_TAUS, 100.0).tolist() == [1.0] * 10  # nothing rendered


def test_window_equals_full_image():
    rng = np.random.default_rng(0)
    test = (500.0 + rng.uniform(-20, 20, (H, W))).astype(np.float32)
    test[rng.random((H, W)) < 0.2] = 0.0
    gt, est = image(), image()
    gt[3:8, 2:9] = (500.0 + rng.normal(0, 5, (5, 7))).astype(np.float32)
    est[4:10, 4:12] = (505.0 + rng.normal(0, 5, (6, 8))).astype(np.float32)
    full = vsd(test, est, gt, K, 15.0, VSD_TAUS, 50.0)
    assert 0.0 < full.min() < full.max() < 1.0
    win = (3, 2, 10, 12)  # rows 3..9, columns 2..11 hold every non-zero pixel of both renders
    outside = np.ones((H, W), bool)
    outside[win[0] : win[2], win[1] : win[3]] = False
    assert not est[outside].any() and not gt[outside].any()
    y0, x0, y1, x1 = win
    crops = vsd(test[y0:y1, x0:x1], est[y0:y1, x0:x1], gt[y0:y1, x0:x1], K, 15.0, VSD_TAUS, 50.0, window=win)
    mixed = vsd(test, est[y0:y1, x0:x1], gt, K, 15.0, VSD_TAUS, 50.0, window=win)  # full arrays are cut
    np.testing.assert_array_equal(crops, full)
    np.testing.assert_array_equal(mixed, full)
    with pytest.raises(ValueError, match="window"):
        vsd(test, est[:3, :3], gt, K, 15.0, VSD_TAUS, 50.0, window=win)


def test_overlapping_sphere_projections():
    assert overlapping_sphere_projections(10.0, [0, 0, 500.0], [0, 0, 600.0]).tolist() == [True]
    assert overlapping_sphere_projections(10.0, [0, 0, 0.0], [0, 0, 600.0]).tolist() == [False]
    # centres 0.04 apart on z = 1, threshold 10 * (1/500 + 1/500) = 0.04: strict, so False
    assert overlapping_sphere_projections(10.0, [10.0, 0, 500.0], [-10.0, 0, 500.0]).tolist() == [False]
    assert overlapping_sphere_projections(10.0, [[9.0, 0, 500.0], [20.0, 0, 500.0]], [-10.0, 0, 500.0]).tolist() == [
        True,
        False,
    ]


def test_matches_official_toolkit_numbers():
    ref = json.loads(FIXTURE.read_text())["vsd"]
    h, w = ref["height"], ref["width"]
    yy, xx = np.mgrid[0:h, 0:w]

    def disc(cy, cx, r, z0, sx, sy):
        d = (z0 + sx * (xx - cx) + sy * (yy - cy)).astype(np.float32)
        return np.where((yy - cy) ** 2 + (xx - cx) ** 2 < r**2, d, np.float32(0))

    def scene(z, amp, hole_period):
        d = (z + amp * np.sin(xx / 3.0) * np.cos(yy / 5.0)).astype(np.float32)
        d[(xx * 7 + yy * 3) % hole_period == 0] = 0
        return d

    assert ref["taus"] == VSD_TAUS.tolist()
    nontrivial = 0
    for case in ref["cases"]:
        gt, est = disc(**case["gt"]), disc(**case["est"])
        test = np.where(gt > 0, np.minimum(scene(**case["scene"]), gt + np.float32(1.0)), scene(**case["scene"]))
        got = vsd(test.astype(np.float32), est, gt, np.asarray(ref["K"]), case["delta"], VSD_TAUS, case["diameter"])
        assert got.tolist() == case["vsd"]  # bit-exact
        win = _bounding_window(est, gt)
        assert (
            vsd(test, est, gt, np.asarray(ref["K"]), case["delta"], VSD_TAUS, case["diameter"], window=win).tolist()
            == case["vsd"]
        )
        nontrivial += 0.0 < min(case["vsd"]) < 1.0 or 0.0 < max(case["vsd"]) < 1.0
    assert nontrivial >= 5
