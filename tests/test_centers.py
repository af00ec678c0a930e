"""Stage 2: peaks -> rays -> 3D centres, on synthetic heatmaps with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from bop_cender.centers import (
    CenterConfig,
    class_agnostic_map,
    closest_points,
    detect_centers,
    find_peaks,
    merge_candidates,
    peak_rays,
    refine_centers,
    sample_scores,
)
from bop_cender.geometry.camera import camera_center_in_world
from bop_cender.synth.rigs import look_at

H, W = 240, 320
K = np.array([[300.0, 0.0, 160.0], [0.0, 300.0, 120.0], [0.0, 0.0, 1.0]])
#: Bilinear sampling peaks at pixel centres, so a refined centre is good to well under a pixel per
#: view: at the cameras' ~720 mm, one pixel is 2.4 mm.
TOL_MM = 0.75 * 720.0 / 300.0


def ring_cameras(n: int, radius: float = 600.0, height: float = 400.0) -> np.ndarray:
    """``(n, 4, 4)`` T_cam_world of cameras on a ring, all looking at the origin."""
    cams = []
    for a in np.linspace(0, 2 * np.pi, n, endpoint=False):
        eye = np.array([radius * np.cos(a), radius * np.sin(a), height])
        cams.append(look_at(eye, np.zeros(3)))
    return np.stack(cams)


def blob_maps(points: np.ndarray, T_cw: np.ndarray, sigma: float = 3.0) -> np.ndarray:
    """``(V, 1, H, W)`` peak-1 Gaussian blobs at the projections of world ``points``, pixel centres at +0.5."""
    u = np.arange(W) + 0.5
    v = np.arange(H) + 0.5
    out = np.zeros((len(T_cw), 1, H, W))
    for i, T in enumerate(T_cw):
        for p in points:
            q = T[:3, :3] @ p + T[:3, 3]
            x, y = (K @ q)[:2] / q[2]
            blob = np.exp(-((u[None] - x) ** 2 + (v[:, None] - y) ** 2) / (2 * sigma**2))
            out[i, 0] = np.maximum(out[i, 0], blob)
    return out


def test_look_at_sees_the_origin():
    T = ring_cameras(4)
    for Tc in T:
        q = Tc[:3, :3] @ np.zeros(3) + Tc[:3, 3]
        x, y = (K @ q)[:2] / q[2]
        assert q[2] > 0 and abs(x - 160) < 1e-6 and abs(y - 120) < 1e-6


def test_closest_points_of_two_known_lines():
    o1, d1 = np.array([0.0, 0, 0]), np.array([1.0, 0, 0])
    o2, d2 = np.array([0.0, 5, 3]), np.array([0.0, 0, 1])  # the z line through (0, 5, .): 5 mm apart
    dist, mid, s, t = closest_points(o1, d1, o2, d2)
    assert dist == pytest.approx(5.0)
    np.testing.assert_allclose(mid, [0.0, 2.5, 0.0], atol=1e-12)
    assert s == pytest.approx(0.0) and t == pytest.approx(-3.0)
    dist, *_ = closest_points(o1, d1, o1 + 1, d1)
    assert np.isinf(dist)  # parallel


def test_peak_pixel_centre_convention():
    m = np.zeros((10, 12))
    m[4, 7] = 1.0
    xy, val = find_peaks(m, 0.5, 1)
    np.testing.assert_allclose(xy, [[7.5, 4.5]])
    o, d = peak_rays(K, np.eye(4), xy)
    np.testing.assert_allclose(o, 0.0)
    p = d[0] / d[0, 2]
    np.testing.assert_allclose((K @ p)[:2], [7.5, 4.5], atol=1e-9)


def test_sample_scores_is_bilinear_at_pixel_centres():
    maps = np.zeros((1, H, W))
    maps[0, 10, 20] = 1.0
    T = np.eye(4)[None]
    # a point that projects exactly to the centre of pixel (row 10, col 20), and one half a pixel right
    z = 500.0
    p_centre = np.array([(20.5 - 160) * z / 300, (10.5 - 120) * z / 300, z])
    p_half = np.array([(21.0 - 160) * z / 300, (10.5 - 120) * z / 300, z])
    s = sample_scores(np.stack([p_centre, p_half, -p_centre]), maps, K[None], T)
    np.testing.assert_allclose(s[:, 0], [1.0, 0.5, 0.0], atol=1e-9)


def test_triangulation_recovers_centres_with_noise_and_outliers():
    rng = np.random.default_rng(3)
    truth = np.array([[0.0, 0.0, 0.0], [80.0, -40.0, 10.0], [-60.0, 70.0, 20.0]])
    T_cw = ring_cameras(6)
    maps = blob_maps(truth, T_cw)
    maps += rng.normal(0, 0.02, maps.shape)
    # an outlier peak in one view only: never confirmed by a second view
    u = np.arange(W) + 0.5
    v = np.arange(H) + 0.5
    maps[2, 0] = np.maximum(maps[2, 0], np.exp(-((u[None] - 20) ** 2 + (v[:, None] - 100) ** 2) / 18))
    maps = np.clip(maps, 0, 1)
    centers = detect_centers(maps, np.repeat(K[None], 6, 0), T_cw, CenterConfig())
    assert len(centers) == 3
    for c in centers:
        err = np.linalg.norm(truth - c.position, axis=1).min()
        assert err < TOL_MM, err
        assert c.view_scores.shape == (6,) and c.score > 4.0


def test_known_count_keeps_the_best_and_drops_close_ones():
    truth = np.array([[0.0, 0.0, 0.0], [100.0, 0.0, 0.0]])
    T_cw = ring_cameras(5)
    weaker = blob_maps(truth[1:], T_cw) * 0.6
    maps = np.maximum(blob_maps(truth[:1], T_cw), weaker)
    centers = detect_centers(maps, np.repeat(K[None], 5, 0), T_cw, CenterConfig(), known_counts={0: 1})
    assert len(centers) == 1
    assert np.linalg.norm(centers[0].position - truth[0]) < TOL_MM


def test_a_point_seen_in_one_view_only_is_rejected():
    T_cw = ring_cameras(4)
    maps = np.zeros((4, 1, H, W))
    maps[1] = blob_maps(np.zeros((1, 3)), T_cw[1:2])[0]
    assert detect_centers(maps, np.repeat(K[None], 4, 0), T_cw, CenterConfig()) == []


def test_merge_is_greedy_by_score():
    pts = np.array([[0.0, 0, 0], [10.0, 0, 0], [25.0, 0, 0], [45.0, 0, 0]])
    scores = np.array([1.0, 1.0, 3.0, 1.0])
    merged = merge_candidates(pts, scores, 30.0)
    # the best (25) takes 0, 10 and 45 (all within 30 of it): one point, pulled towards 25
    assert merged.shape == (1, 3)
    assert 15 < merged[0, 0] < 30


def test_merge_matches_the_all_pairs_reference():
    """The merge computes one row of distances per merged point; the result is the all-pairs version's, bit for bit
    (random clouds with equal scores and duplicate points too)."""
    rng = np.random.default_rng(3)
    for n in (1, 2, 50, 400):
        pts = rng.normal(0.0, 20.0, (n, 3))
        pts[n // 2 :: 7] = pts[0]  # duplicates
        scores = rng.integers(0, 4, n).astype(float)  # ties
        order = np.argsort(-scores, kind="stable")
        ref_pts, sc = pts[order], np.maximum(scores[order], 1e-12)
        dist = np.linalg.norm(ref_pts[:, None] - ref_pts[None], axis=-1)
        free, ref = np.ones(n, bool), []
        for k in range(n):
            if free[k]:
                group = free & (dist[k] < 10.0)
                free &= ~group
                ref.append((ref_pts[group] * sc[group][:, None]).sum(0) / sc[group].sum())
        np.testing.assert_array_equal(merge_candidates(pts, scores, 10.0), np.asarray(ref))


def test_the_class_agnostic_map_sums_exclusive_channels_and_joins_independent_ones_by_noisy_or():
    """Exclusive channels (a factored network's): the sum, clipped. Independent ones (the oracle's): 1 - prod(1 - p),
    which keeps one peak of 1 per part where two parts' unit blobs of different ids overlap; their clipped sum is a
    plateau of 1 between them that the peak finder returns as a grid of peaks."""
    rng = np.random.default_rng(4)
    maps = rng.random((2, 3, 5, 6))
    np.testing.assert_allclose(class_agnostic_map(maps, True), np.clip(maps.sum(1, keepdims=True), 0, 1))
    np.testing.assert_allclose(class_agnostic_map(maps, False), 1 - np.prod(1 - maps, axis=1, keepdims=True))
    T_cw = ring_cameras(1)
    truth = np.array([[0.0, 0.0, 0.0], [15.0, 0.0, 0.0]])  # 6 px apart, sigma 4 px: the blobs overlap
    two = np.concatenate([blob_maps(truth[:1], T_cw, 4.0), blob_maps(truth[1:], T_cw, 4.0)], axis=1)
    assert len(find_peaks(class_agnostic_map(two, True)[0, 0], 0.15, 2)[0]) > 2  # the clipped sum's plateau
    xy, values = find_peaks(class_agnostic_map(two, False)[0, 0], 0.15, 2)
    expected = np.array([np.unravel_index(np.argmax(two[0, c]), (H, W))[::-1] for c in range(2)]) + 0.5
    assert len(xy) == 2 and np.all(values > 0.99)  # a blob centred on a pixel edge: either pixel is its peak
    assert np.abs(np.sort(xy, axis=0) - np.sort(expected, axis=0)).max() <= 1.0


def test_detect_centers_joins_the_channels_as_told(monkeypatch):
    """``exclusive_channels`` reaches :func:`class_agnostic_map` (the factored network's rows depend on it: its sum)."""
    import bop_cender.centers as centers_module

    seen = []

    def spy(maps, exclusive):
        seen.append(exclusive)
        return class_agnostic_map(maps, exclusive)

    monkeypatch.setattr(centers_module, "class_agnostic_map", spy)
    T_cw = ring_cameras(3)
    maps = np.concatenate([blob_maps(np.zeros((1, 3)), T_cw)] * 2, axis=1)
    for exclusive in (True, False):
        detect_centers(maps, np.repeat(K[None], 3, 0), T_cw, CenterConfig(), (1, 2), None, exclusive)
    assert seen == [True, False]


def test_oracle_like_channels_of_two_overlapping_parts_give_both_centres():
    """Two parts 15 mm apart with unit blobs in their own channels (as the oracle's maps): both centres found,
    each named by its channel, from a handful of peaks (not a plateau's grid)."""
    truth = np.array([[0.0, 0.0, 0.0], [15.0, 0.0, 0.0]])
    T_cw = ring_cameras(5)
    Ks = np.repeat(K[None], 5, 0)
    maps = np.concatenate([blob_maps(truth[:1], T_cw, 4.0), blob_maps(truth[1:], T_cw, 4.0)], axis=1)
    found = detect_centers(maps, Ks, T_cw, CenterConfig(), (11, 12), {0: 1, 1: 1})
    assert [c.obj_id for c in found] == [11, 12]
    np.testing.assert_array_less(np.linalg.norm([c.position for c in found] - truth, axis=1), TOL_MM)


def test_two_objects_closer_than_the_old_d_o_are_both_kept():
    # piled flanges: centres 8 mm apart, their blobs overlap (one peak in views along the line joining
    # them); each keeps its own peaks in the other views, so both are kept (d_o = 10 had dropped one)
    truth = np.array([[0.0, 0.0, 0.0], [8.0, 0.0, 0.0]])
    T_cw = ring_cameras(6)
    maps = blob_maps(truth, T_cw, sigma=2.0)
    centers = detect_centers(maps, np.repeat(K[None], 6, 0), T_cw, CenterConfig(), known_counts={0: 2})
    assert len(centers) == 2
    err = np.linalg.norm(truth[:, None] - np.array([c.position for c in centers])[None], axis=-1).min(1)
    assert (err < TOL_MM).all(), err


def test_a_phantom_where_other_objects_rays_cross_loses_to_a_part_seen_in_two_views():
    # the rays of cameras 0, 1 and 2 through P each meet a different object (A, B, C, seen everywhere),
    # so P scores ~3 on their blobs; D shows its centre in views 3 and 4 only (score ~2). With the known
    # count 4 the top-4 by score took P; P's peaks are A's, B's and C's, so D is kept instead.
    T_cw = ring_cameras(6)
    P = np.array([0.0, 0.0, 0.0])
    on_rays = []
    for i, t in zip(range(3), (90.0, -90.0, 120.0), strict=True):
        eye = camera_center_in_world(T_cw[i])
        on_rays.append(P + t * (P - eye) / np.linalg.norm(P - eye))
    D = np.array([-40.0, 150.0, 10.0])
    maps = blob_maps(np.stack(on_rays), T_cw)
    maps[3:5] = np.maximum(maps[3:5], blob_maps(D[None], T_cw[3:5]))
    truth = np.vstack([on_rays, D])
    Ks = np.repeat(K[None], 6, 0)
    assert sample_scores(P[None], maps[:, 0], Ks, T_cw)[0].sum() > 2.5  # the phantom outscores D
    centers = detect_centers(maps, Ks, T_cw, CenterConfig(), known_counts={0: 4})
    found = np.array([c.position for c in centers])
    err = np.linalg.norm(truth[:, None] - found[None], axis=-1).min(1)
    assert (err < TOL_MM).all(), err
    assert np.linalg.norm(found - P, axis=1).min() > 20.0


def test_refined_duplicates_are_one_centre_without_a_known_count():
    # every pair of rays gives a candidate; those merged apart converge to the same centre when
    # refined: its peaks are owned by the first, so the others are dropped
    truth = np.array([[0.0, 0.0, 0.0], [60.0, 0.0, 0.0]])
    T_cw = ring_cameras(8)
    maps = blob_maps(truth, T_cw)
    centers = detect_centers(maps, np.repeat(K[None], 8, 0), T_cw, CenterConfig(d_c=1.0))
    assert len(centers) == 2


def test_refine_centers_moves_every_start_to_its_own_blob_at_once():
    """All starts step together, each to the maximum of the summed score nearest it; a start on nothing
    (score 0 everywhere around) stays put."""
    T = ring_cameras(5)
    truth = np.array([[0.0, 0.0, 0.0], [60.0, -30.0, 20.0]])
    maps = blob_maps(truth, T)[:, 0]
    starts = np.array([[3.0, -2.0, 2.5], [57.0, -27.0, 23.0], [400.0, 400.0, 400.0]])
    out = refine_centers(starts, maps, np.repeat(K[None], len(T), 0), T, CenterConfig())
    assert out.shape == (3, 3)
    np.testing.assert_array_less(np.linalg.norm(out[:2] - truth, axis=1), TOL_MM)
    np.testing.assert_array_equal(out[2], starts[2])
    assert refine_centers(np.zeros((0, 3)), maps, np.repeat(K[None], len(T), 0), T, CenterConfig()).shape == (0, 3)


def test_class_agnostic_centres_find_a_part_whose_peak_is_split_over_channels_and_name_it_by_the_best_channel():
    """Three channels (object ids 11, 12, 13). Part A is sure of its id (channel 0, peak 0.9); part B's peak is split
    0.13 / 0.12 over channels 1 and 2, under the peak threshold 0.15 in each: per channel it is lost, on the sum
    it is found and named 12 (channel 1, its larger share); with channel 1's count used up it goes to channel 2;
    with none left it is dropped."""
    truth = np.array([[0.0, 0.0, 0.0], [90.0, -30.0, 10.0]])
    T_cw = ring_cameras(5)
    Ks = np.repeat(K[None], 5, 0)
    a, b = blob_maps(truth[:1], T_cw)[:, 0], blob_maps(truth[1:], T_cw)[:, 0]
    maps = np.stack([0.9 * a, 0.13 * b, 0.12 * b], axis=1)  # (V, 3, H, W)
    ids, counts = (11, 12, 13), {0: 1, 1: 1, 2: 1}
    per_channel = detect_centers(maps, Ks, T_cw, CenterConfig(class_agnostic=False), ids, counts)
    assert [c.obj_id for c in per_channel] == [11]
    agnostic = CenterConfig()  # class-agnostic by default
    found = detect_centers(maps, Ks, T_cw, agnostic, ids, counts)
    assert [(c.channel, c.obj_id) for c in found] == [(0, 11), (1, 12)]
    assert np.linalg.norm(found[1].position - truth[1]) < TOL_MM
    assert np.allclose(found[1].view_scores, sample_scores(found[1].position[None], maps[:, 1], Ks, T_cw)[0])
    found = detect_centers(maps, Ks, T_cw, agnostic, ids, {0: 1, 1: 0, 2: 1})
    assert [(c.channel, c.obj_id) for c in found] == [(0, 11), (2, 13)]
    assert [c.obj_id for c in detect_centers(maps, Ks, T_cw, agnostic, ids, {0: 1, 1: 0, 2: 0})] == [11]
    # one channel (DIMO): the option changes nothing
    one = maps[:, :1]
    per_channel_config = CenterConfig(class_agnostic=False)
    same = detect_centers(one, Ks, T_cw, agnostic, None, {0: 1})
    assert [c.position.tolist() for c in same] == [
        c.position.tolist() for c in detect_centers(one, Ks, T_cw, per_channel_config, None, {0: 1})
    ]
