import numpy as np
import pytest

from bop_cender.geometry.camera import camera_center_in_world, project_points
from bop_cender.geometry.poses import transform_points
from bop_cender.geometry.rotations import orthonormality_error
from bop_cender.synth.rigs import (
    TLESS_FX,
    dimo_rig,
    look_at,
    tless_cameras,
)


def _project(K: np.ndarray, T_cam_world: np.ndarray, points_world) -> np.ndarray:
    return project_points(K, transform_points(T_cam_world, np.asarray(points_world, dtype=np.float64)))


# ------------------------------------------------------------------------------------------ look_at


@pytest.mark.parametrize(
    "eye, target",
    [((500.0, 0.0, 300.0), (0.0, 0.0, 0.0)), ((-120.0, 340.0, 80.0), (10.0, -20.0, 30.0)), ((0, 1, 900), (0, 0, 0))],
)
def test_look_at_puts_target_on_optical_axis_in_front(eye, target):
    T = look_at(eye, target)
    p = transform_points(T, np.array([target], dtype=np.float64))[0]
    np.testing.assert_allclose(p[:2], 0.0, atol=1e-9)
    assert p[2] == pytest.approx(np.linalg.norm(np.subtract(target, eye)))
    np.testing.assert_allclose(camera_center_in_world(T), eye, atol=1e-9)
    assert orthonormality_error(T[:3, :3]) < 1e-12
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)


def test_look_at_axes_are_opencv():
    # camera on the -y side of the origin, level, looking along +y: x right = +x, y down = -z
    T = look_at((0.0, -500.0, 0.0), (0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0))
    np.testing.assert_allclose(T[:3, :3], [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)


def test_look_at_up_appears_up_in_image():
    K = np.array([[500.0, 0, 160], [0, 500.0, 128], [0, 0, 1]])
    T = look_at((400.0, 300.0, 350.0), (0.0, 0.0, 0.0))
    uv = _project(K, T, [[0, 0, 0], [0, 0, 50]])
    assert uv[1, 1] < uv[0, 1] - 10  # a point above the target is higher on screen (smaller v)
    assert uv[1, 0] == pytest.approx(uv[0, 0], abs=1e-9)  # and straight above it: no roll


def test_look_at_rejects_degenerate_input():
    with pytest.raises(ValueError, match="parallel"):
        look_at((0, 0, 500), (0, 0, 0), up=(0, 0, 1))
    with pytest.raises(ValueError, match="coincide"):
        look_at((1, 2, 3), (1, 2, 3))


# ------------------------------------------------------------------------------------------ DIMO


def test_dimo_rig_shape_and_ids():
    rig = dimo_rig()
    assert [vid for vid, _, _ in rig] == list(range(13))
    for _, K, T in rig:
        assert K.shape == (3, 3) and T.shape == (4, 4)
        np.testing.assert_allclose(K[:2, 2], [160.0, 128.0])
        assert orthonormality_error(T[:3, :3]) < 1e-12


def test_dimo_rig_is_fixed_across_calls():
    a, b = dimo_rig(), dimo_rig()
    for (ia, Ka, Ta), (ib, Kb, Tb) in zip(a, b, strict=True):
        assert ia == ib
        np.testing.assert_array_equal(Ka, Kb)
        np.testing.assert_array_equal(Ta, Tb)


def test_dimo_rig_sees_pile_centre_and_pile_region():
    # the target and a 240 x 160 mm carrier footprint with a 100 mm pile on it stay inside every image
    corners = np.array([[x, y, z] for x in (-120, 120) for y in (-80, 80) for z in (0, 100)], dtype=np.float64)
    for vid, K, T in dimo_rig():
        uv = _project(K, T, np.vstack([[0, 0, 0], corners]))
        assert np.all(transform_points(T, corners)[:, 2] > 0), vid
        assert np.all((uv >= 0) & (uv <= [320, 256])), (vid, uv.round(1))
        np.testing.assert_allclose(uv[0], [160.0, 128.0], atol=1e-9)
        # and fills a good part of it
        span = uv[1:].max(axis=0) - uv[1:].min(axis=0)
        assert span[0] > 0.4 * 320, (vid, span)


def test_dimo_rig_is_upright_without_roll_flips():
    rig = dimo_rig()
    for vid, K, T in rig[1:]:
        uv = _project(K, T, [[0, 0, 0], [0, 0, 60]])
        assert uv[1, 1] < uv[0, 1], vid  # world up is up on screen
        assert uv[1, 0] == pytest.approx(uv[0, 0], abs=1e-9)
    # top view: image up is world -x, as for the ring camera at azimuth 0 (viewpoint 1)
    for vid in (0, 1):
        _, K, T = rig[vid]
        uv = _project(K, T, [[0, 0, 0], [-60, 0, 0]])
        assert uv[1, 1] < uv[0, 1] - 10, vid
        assert uv[1, 0] == pytest.approx(uv[0, 0], abs=1e-6), vid


def test_dimo_even_viewpoints_surround_the_pile():
    rig = dimo_rig()
    quadrants = set()
    for vid, _, T in rig[2::2]:
        c = camera_center_in_world(T)
        assert np.hypot(c[0], c[1]) > 100.0, vid
        quadrants.add(int(np.floor(np.arctan2(c[1], c[0]) / (np.pi / 2))) % 4)
    assert len(quadrants) >= 3
    # and the top view is straight above
    np.testing.assert_allclose(camera_center_in_world(rig[0][2])[:2], 0.0, atol=1e-9)


def test_dimo_rig_other_counts_and_target():
    rig = dimo_rig(n_viewpoints=7, target=(10.0, -5.0, 20.0))
    assert len(rig) == 7
    for _, K, T in rig:
        np.testing.assert_allclose(_project(K, T, [[10.0, -5.0, 20.0]])[0], [160.0, 128.0], atol=1e-9)


# ------------------------------------------------------------------------------------------ T-LESS


def test_tless_cameras_distances_elevations_and_view():
    target = np.array([5.0, -10.0, 40.0])
    cams = tless_cameras(40, np.random.default_rng(0), target=target, look_at_offset_mm=20.0)
    assert len(cams) == 40
    for K, T in cams:
        c = camera_center_in_world(T)
        assert 650.0 <= np.linalg.norm(c - target) <= 940.0
        elevation = np.degrees(np.arcsin((c - target)[2] / np.linalg.norm(c - target)))
        assert 15.0 <= elevation <= 75.0
        assert K[0, 0] == pytest.approx(TLESS_FX)
        assert abs(K[0, 2] - 360.0) <= 8.0 and abs(K[1, 2] - 270.0) <= 8.0
        uv = _project(K, T, [target])[0]
        assert 0 < uv[0] < 720 and 0 < uv[1] < 540
        assert transform_points(T, target[None])[0, 2] > 0
        assert uv[1] < _project(K, T, [target - [0, 0, 50]])[0, 1]  # upright: lower point is lower on screen


def test_tless_cameras_per_image_K_differ_and_azimuths_spread():
    cams = tless_cameras(30, np.random.default_rng(1))
    principal = np.array([K[:2, 2] for K, _ in cams])
    assert len(np.unique(principal, axis=0)) == 30
    centres = np.array([camera_center_in_world(T) for _, T in cams])
    quadrants = {int(np.floor(np.arctan2(y, x) / (np.pi / 2))) % 4 for x, y, _ in centres}
    assert quadrants == {0, 1, 2, 3}


def test_tless_cameras_deterministic_per_seed():
    a = tless_cameras(5, np.random.default_rng(7))
    b = tless_cameras(5, np.random.default_rng(7))
    c = tless_cameras(5, np.random.default_rng(8))
    for (Ka, Ta), (Kb, Tb) in zip(a, b, strict=True):
        np.testing.assert_array_equal(Ka, Kb)
        np.testing.assert_array_equal(Ta, Tb)
    assert not np.array_equal(a[0][1], c[0][1])
