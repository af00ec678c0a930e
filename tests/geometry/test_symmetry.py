import math

import numpy as np
import pytest

from bop_cender.geometry import (
    ContinuousSymmetry,
    apply_symmetries_to_pose,
    continuous_step_count,
    symmetries_from_model_info,
    symmetry_transforms,
)
from bop_cender.geometry.poses import make_pose, transform_points

FLIP_X = [1.0, 0, 0, 0, 0, -1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1]


def test_step_count_bop19():
    assert continuous_step_count(0.01) == 315
    assert continuous_step_count(math.pi / 4) == 4


def test_discrete_only_identity_first():
    R, t = symmetry_transforms([FLIP_X])
    assert R.shape == (2, 3, 3) and t.shape == (2, 3)
    np.testing.assert_array_equal(R[0], np.eye(3))
    np.testing.assert_array_equal(R[1], np.diag([1.0, -1, -1]))


def test_discrete_translation_kept():
    m = np.eye(4)
    m[:3, :3] = np.diag([-1.0, -1, 1])
    m[:3, 3] = [2.0, 0, 0]
    R, t = symmetry_transforms([m.ravel().tolist()])
    np.testing.assert_array_equal(t[1], [2.0, 0, 0])


def test_continuous_steps_and_offset():
    sym = ContinuousSymmetry(axis=(0.0, 0.0, 2.0), offset=(10.0, 0.0, 0.0))
    R, t = symmetry_transforms([], [sym], max_sym_disc_step=math.pi / 4)  # 4 steps of 90 degrees
    assert R.shape == (4, 3, 3)
    np.testing.assert_allclose(R[0], np.eye(3), atol=1e-15)
    np.testing.assert_allclose(R[1] @ [1.0, 0, 0], [0, 1, 0], atol=1e-12)
    # Rotation about the axis through (10, 0, 0): that point is fixed.
    pts = transform_points(make_pose(R, t), np.array([[10.0, 0.0, 5.0]]))
    np.testing.assert_allclose(pts[:, 0], np.tile([10.0, 0.0, 5.0], (4, 1)), atol=1e-12)
    np.testing.assert_allclose(t[1], -R[1] @ [10.0, 0, 0] + [10.0, 0, 0])


def test_combination_order_discrete_outer():
    sym = ContinuousSymmetry(axis=(0.0, 0.0, 1.0))
    R, t = symmetry_transforms([FLIP_X], [sym])
    n = 315
    assert R.shape == (2 * n, 3, 3)
    Rc1, _ = symmetry_transforms([], [sym])
    np.testing.assert_allclose(R[:n], Rc1)  # identity discrete first
    np.testing.assert_allclose(R[n + 5], Rc1[5] @ np.diag([1.0, -1, -1]))


def test_apply_symmetries_to_pose():
    R_gt = np.eye(3)
    t_gt = np.array([0.0, 0.0, 500.0])
    sR, st = symmetry_transforms([FLIP_X])
    Rs, ts = apply_symmetries_to_pose(R_gt, t_gt, sR, st)
    np.testing.assert_allclose(Rs[1], np.diag([1.0, -1, -1]))
    np.testing.assert_allclose(ts[1], t_gt)


def test_models_info_parsing_and_errors():
    d, c = symmetries_from_model_info(
        {"symmetries_discrete": [FLIP_X], "symmetries_continuous": [{"axis": [0, 0, 1], "offset": [0, 0, 0]}]}
    )
    assert len(d) == 1 and c[0].axis == (0.0, 0.0, 1.0)
    with pytest.raises(ValueError, match="symmetries_discrete\\[0\\]"):
        symmetries_from_model_info({"symmetries_discrete": [[1, 2, 3]]})
    with pytest.raises(ValueError, match="zero vector"):
        symmetries_from_model_info({"symmetries_continuous": [{"axis": [0, 0, 0], "offset": [0, 0, 0]}]})
    with pytest.raises(ValueError, match="finite"):
        symmetries_from_model_info({"symmetries_continuous": [{"axis": [0, float("nan"), 1], "offset": [0, 0, 0]}]})
