import numpy as np
import pytest

from bop_cender.geometry import (
    axis_angle_to_rotmat,
    orthonormality_error,
    quat_to_rotmat,
    random_rotations,
    rotation_angle,
    rotmat_to_quat,
    rotmat_to_rotvec,
    rotvec_to_rotmat,
)


def test_rotvec_round_trip():
    rng = np.random.default_rng(0)
    R = random_rotations(50, rng)
    np.testing.assert_allclose(rotvec_to_rotmat(rotmat_to_rotvec(R)), R, atol=1e-12)


def test_quat_round_trip_scalar_last():
    rng = np.random.default_rng(1)
    R = random_rotations(50, rng)
    q = rotmat_to_quat(R)
    assert np.all(q[:, 3] >= 0)
    np.testing.assert_allclose(quat_to_rotmat(q), R, atol=1e-12)
    np.testing.assert_allclose(quat_to_rotmat([0, 0, 0, 1.0]), np.eye(3))


def test_axis_angle():
    R = axis_angle_to_rotmat([0, 0, 2.0], np.pi / 2)
    np.testing.assert_allclose(R @ [1.0, 0, 0], [0, 1, 0], atol=1e-12)
    assert rotation_angle(R) == pytest.approx(np.pi / 2)


def test_random_rotations_deterministic_and_uniform():
    a = random_rotations(2000, np.random.default_rng(7))
    b = random_rotations(2000, np.random.default_rng(7))
    np.testing.assert_array_equal(a, b)
    assert orthonormality_error(a).max() < 1e-12
    assert np.all(np.linalg.det(a) > 0)
    # Haar measure: the mean rotation matrix is ~0 and the angle density is (1 - cos)/pi: mean angle pi/2 + 2/pi.
    assert np.abs(a.mean(axis=0)).max() < 0.05
    assert rotation_angle(a).mean() == pytest.approx(np.pi / 2 + 2 / np.pi, abs=0.05)


def test_orthonormality_error():
    assert orthonormality_error(np.eye(3)) == 0
    assert orthonormality_error(np.diag([1.0, 1.0, 1.1])) == pytest.approx(0.21)
