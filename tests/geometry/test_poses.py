import numpy as np
import pytest

from bop_cender.geometry import (
    c2w_to_w2c,
    compose,
    invert_pose,
    make_pose,
    pose_from_bop,
    pose_residual,
    random_rotations,
    transform_points,
    w2c_to_c2w,
)


@pytest.fixture
def rng():
    return np.random.default_rng(0)


def random_pose(rng, n=None):
    R = random_rotations(1 if n is None else n, rng)
    t = rng.normal(scale=300.0, size=(R.shape[0], 3))
    T = make_pose(R, t)
    return T[0] if n is None else T


def test_make_pose_layout():
    R = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    T = make_pose(R, [1, 2, 3])
    assert T.shape == (4, 4)
    np.testing.assert_array_equal(T[:3, :3], R)
    np.testing.assert_array_equal(T[:3, 3], [1, 2, 3])
    np.testing.assert_array_equal(T[3], [0, 0, 0, 1])


def test_pose_from_bop_is_row_major():
    # 30 degrees about z, the BOP results row of docs/datasets.md ("BOP results files").
    T = pose_from_bop([0.866025, -0.5, 0.0, 0.5, 0.866025, 0.0, 0.0, 0.0, 1.0], [12.3, -45.6, 720.1])
    np.testing.assert_allclose(transform_points(T, [[1.0, 0, 0]])[0], [12.3 + 0.866025, -45.6 + 0.5, 720.1])


def test_invert_round_trip(rng):
    T = random_pose(rng, 5)
    np.testing.assert_allclose(invert_pose(T) @ T, np.broadcast_to(np.eye(4), (5, 4, 4)), atol=1e-12)
    np.testing.assert_allclose(invert_pose(invert_pose(T)), T, atol=1e-12)


def test_c2w_w2c_round_trip(rng):
    T_world_cam = random_pose(rng)
    T_cam_world = c2w_to_w2c(T_world_cam)
    np.testing.assert_allclose(w2c_to_c2w(T_cam_world), T_world_cam, atol=1e-12)
    # The camera centre maps to the camera origin.
    centre = T_world_cam[:3, 3]
    np.testing.assert_allclose(transform_points(T_cam_world, centre[None])[0], 0.0, atol=1e-9)


def test_compose_order(rng):
    T_c_b, T_b_a = random_pose(rng), random_pose(rng)
    p = rng.normal(size=(7, 3))
    np.testing.assert_allclose(
        transform_points(compose(T_c_b, T_b_a), p), transform_points(T_c_b, transform_points(T_b_a, p)), atol=1e-9
    )


def test_transform_points_batched(rng):
    T = random_pose(rng, 3)
    p = rng.normal(size=(4, 3))
    out = transform_points(T, p)
    assert out.shape == (3, 4, 3)
    for i in range(3):
        np.testing.assert_allclose(out[i], transform_points(T[i], p), atol=1e-12)


def test_pose_residual(rng):
    T = random_pose(rng)
    dt, dr = pose_residual(T, T)
    assert dt == pytest.approx(0.0, abs=1e-9) and dr == pytest.approx(0.0, abs=1e-6)
    T2 = T.copy()
    T2[:3, 3] += [3.0, 4.0, 0.0]
    assert pose_residual(T, T2)[0] == pytest.approx(5.0)
    Rz = make_pose(np.array([[np.cos(0.1), -np.sin(0.1), 0], [np.sin(0.1), np.cos(0.1), 0], [0, 0, 1]]), [0, 0, 0])
    assert pose_residual(T, T @ Rz)[1] == pytest.approx(0.1, abs=1e-9)
