import json

import numpy as np
import pytest

from bop_cender.data.models import load_models
from bop_cender.data.types import CameraView, Dataset, GtObject, ObjectModel, Scene, check_pose
from bop_cender.errors import DatasetError

K = np.array([[600.0, 0, 160], [0, 600, 128], [0, 0, 1]])


def view(im_id=0, **kw):
    args = {
        "im_id": im_id,
        "K": K,
        "T_cam_world": np.eye(4),
        "width": 320,
        "height": 256,
        "source": "scene_camera.json",
    }
    args.update(kw)
    return CameraView(**args)


def test_camera_view_validates():
    v = view()
    np.testing.assert_array_equal(v.T_world_cam, np.eye(4))
    bad = np.eye(4)
    bad[0, 0] = 1.2
    with pytest.raises(DatasetError, match=r"scene_camera.json: image 0: T_cam_world: rotation is not orthonormal"):
        view(T_cam_world=bad)
    nan = np.eye(4)
    nan[0, 3] = np.nan
    with pytest.raises(DatasetError, match="NaN"):
        view(T_cam_world=nan)
    with pytest.raises(DatasetError, match=r"image 0: K: expected shape \(3, 3\)"):
        view(K=np.eye(2))
    with pytest.raises(DatasetError, match="fx, fy > 0"):
        view(K=np.diag([-1.0, 1, 1]))
    with pytest.raises(DatasetError, match="depth_scale"):
        view(depth_scale=0.0)


def test_reflection_rejected():
    T = np.diag([1.0, 1, -1, 1])
    with pytest.raises(DatasetError, match="det"):
        check_pose(T, "R")


def test_object_model_centre_and_symmetry(tmp_path):
    m = ObjectModel(
        obj_id=1,
        path=tmp_path / "obj_000001.ply",
        diameter=50.0,
        bbox_min=[-10.0, -20.0, -5.0],
        bbox_size=[20.0, 30.0, 10.0],
        symmetries_discrete=[[1.0, 0, 0, 0, 0, -1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1]],
    )
    np.testing.assert_array_equal(m.center, [0.0, -5.0, 0.0])
    assert m.is_symmetric
    R, t = m.symmetry_transforms()
    assert R.shape == (2, 3, 3)
    assert m.symmetry_transforms()[0] is R and not R.flags.writeable and not t.flags.writeable  # made once, shared
    finer, _ = m.symmetry_transforms(max_sym_disc_step=0.001)  # another step: computed, the shared set untouched
    assert finer is not R and finer.flags.writeable and np.array_equal(finer, R)
    with pytest.raises(DatasetError, match="diameter"):
        ObjectModel(obj_id=2, path=tmp_path, diameter=float("nan"), bbox_min=[0, 0, 0], bbox_size=[1, 1, 1])


def test_scene_keys_and_duplicate_views():
    s = Scene("tless", "test", "000001", (view(0), view(3)), key_suffix="g02")
    assert s.key == "000001/g02" and s.im_ids == [0, 3]
    assert s.view(3).im_id == 3
    assert Scene("dimo", "real", "000004", (view(0),)).key == "000004"
    with pytest.raises(DatasetError, match="duplicate image ids"):
        Scene("dimo", "real", "000004", (view(0), view(0)))


def test_gt_object_validates():
    GtObject(obj_id=1, T_world_model=np.eye(4))
    with pytest.raises(DatasetError, match="obj 1: T_world_model"):
        GtObject(obj_id=1, T_world_model=np.zeros((3, 3)))


def test_dataset_lazy_and_unknown_key(tmp_path):
    calls = []

    def loader(key):
        calls.append(key)
        return Scene("dimo", "real", key, (view(0),))

    ds = Dataset(root=tmp_path, name="dimo", split="real", models={}, scene_keys=["000000", "000001"], loader=loader)
    assert calls == []
    assert ds.scene("000001").scene_id == "000001"
    ds.scene("000001")
    assert calls == ["000001"]
    assert [s.scene_id for s in ds.scenes()] == ["000000", "000001"]
    with pytest.raises(DatasetError, match="unknown scene"):
        ds.scene("000009")


def test_load_models_errors(tmp_path):
    d = tmp_path / "models"
    with pytest.raises(DatasetError, match="models folder not found"):
        load_models(d)
    d.mkdir()
    (d / "models_info.json").write_text('{"1": {"diameter": 10, "min_x": 0}}')
    with pytest.raises(DatasetError, match=r"models_info.json: 1: missing key 'min_y'"):
        load_models(d)
    entry = '"diameter": 10, "min_x": 0, "min_y": 0, "min_z": 0, "size_x": 8, "size_y": 5, "size_z": "x"'
    (d / "models_info.json").write_text('{"1": {' + entry + "}}")
    with pytest.raises(DatasetError, match=r"1.size_z: expected a number"):
        load_models(d)
    good = {"diameter": 10, "min_x": 0, "min_y": 0, "min_z": 0, "size_x": 8, "size_y": 5, "size_z": 1}
    for key, bad in (("size_z", -1), ("diameter", 0), ("size_x", -0.5)):
        (d / "models_info.json").write_text(json.dumps({"1": {**good, key: bad}}))
        with pytest.raises(
            DatasetError, match=rf"models_info.json: 1.{key}: expected a positive number \(mm\), got {bad}"
        ):
            load_models(d)
    for diameter in (0.01, 40):  # in metres; beyond the box's diagonal (9.5)
        (d / "models_info.json").write_text(json.dumps({"1": {**good, "diameter": diameter}}))
        with pytest.raises(DatasetError, match=rf"models_info.json: 1.diameter: diameter {diameter:g} mm does not fit"):
            load_models(d)
    entry = entry.replace('"x"', "1")
    (d / "models_info.json").write_text('{"1": {' + entry + "}}")
    with pytest.raises(DatasetError, match=r"obj_000001.ply: model of object 1"):
        load_models(d)
    (d / "obj_000001.ply").write_text("placeholder: not read until the mesh is used")
    models = load_models(d, is_target=lambda i: i < 100)
    assert models[1].is_target and models[1].diameter == 10
