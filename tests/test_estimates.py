"""ObjectEstimate / SceneEstimate: validated where they are made."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bop_cender.errors import DatasetError
from bop_cender.estimates import ObjectEstimate, SceneEstimate
from bop_cender.geometry.poses import make_pose


def _pose(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return make_pose(Rotation.random(random_state=rng).as_matrix(), rng.normal(0, 100, 3))


def test_object_estimate_keeps_pose_read_only_copy() -> None:
    T = _pose()
    est = ObjectEstimate(obj_id=np.int64(3), T_world_model=T, score=0.5)
    assert est.obj_id == 3 and type(est.obj_id) is int
    assert np.array_equal(est.T_world_model, T) and est.T_world_model is not T
    assert est.T_world_model.dtype == np.float64 and not est.T_world_model.flags.writeable
    T[0, 3] = 1e6  # the caller's array stays the caller's
    assert est.T_world_model[0, 3] != 1e6


@pytest.mark.parametrize(
    "change, error",
    [
        (lambda T: T.__setitem__((0, 0), np.nan), DatasetError),
        (lambda T: T.__setitem__((0, 0), T[0, 0] * 1.1), DatasetError),  # not orthonormal
        (lambda T: T.__setitem__((slice(None, 3), 0), -T[:3, 0]), DatasetError),  # det -1
        (lambda T: T.__setitem__((3, 0), 1.0), DatasetError),  # last row
    ],
)
def test_object_estimate_rejects_bad_pose(change, error) -> None:
    T = _pose()
    change(T)
    with pytest.raises(error, match="obj 1"):
        ObjectEstimate(1, T, 0.5)


@pytest.mark.parametrize("obj_id, score", [(-1, 0.5), (True, 0.5), (1.0, 0.5), (1, np.nan), (1, np.inf), (1, "x")])
def test_object_estimate_rejects_bad_id_or_score(obj_id, score) -> None:
    with pytest.raises(ValueError):
        ObjectEstimate(obj_id, _pose(), score)


def test_scene_estimate_validates() -> None:
    objs = [ObjectEstimate(1, _pose(1), 0.9), ObjectEstimate(2, _pose(2), 0.4)]
    est = SceneEstimate("000123_17/g01", "000123_17", objs, time_s=np.float32(1.5), timings={"poses": 1})
    assert isinstance(est.objects, tuple) and len(est.objects) == 2
    assert est.time_s == 1.5 and est.timings == {"poses": 1.0}
    with pytest.raises(ValueError, match="does not belong"):
        SceneEstimate("000124", "000123", objs, 1.0)
    with pytest.raises(ValueError, match="neither"):
        SceneEstimate("scene1", "scene1", objs, 1.0)
    with pytest.raises(ValueError, match="time_s"):
        SceneEstimate("000123", "000123", objs, float("nan"))
    with pytest.raises(ValueError, match="timings"):
        SceneEstimate("000123", "000123", objs, 1.0, {"poses": float("inf")})
    with pytest.raises(TypeError, match="ObjectEstimate"):
        SceneEstimate("000123", "000123", [(1, _pose(), 0.5)], 1.0)
