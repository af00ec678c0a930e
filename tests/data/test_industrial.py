"""The BOP-Industrial multi-sensor reader on small splits written by ``industrial_builder``.

MINI: 2 scenes of 2 captures, 3 sensors of different sizes (``gcam`` gray, evaluated; ``ccam`` RGB; ``dcam`` gray and
depth). BIG: the same shape with XYZ-IBD's own sensors and sizes (the table's), read by name and by ``--dataset bop``,
and compared with the official toolkit's readers where ``BOP_TOOLKIT_DIR`` names a checkout (else where
``bop_toolkit_lib`` imports; skipped otherwise).
"""

from __future__ import annotations

import importlib
import json
import os
import pickle
import shutil
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from bop_cender.data.industrial import open_industrial
from bop_cender.data.industrial_params import INDUSTRIAL, IndustrialSpec
from bop_cender.data.industrial_scene import VIEW_ID_STRIDE
from bop_cender.data.registry import DATASETS, DatasetRequest, open_dataset
from bop_cender.data.types import Sensor
from bop_cender.errors import ConfigError, DatasetError
from bop_cender.estimates import ObjectEstimate, SceneEstimate
from bop_cender.eval.ground_truth import collect_ground_truth
from bop_cender.geometry.poses import pose_from_bop
from bop_cender.results.bop_csv import scene_estimates_to_rows

try:
    from tests.data.bop_builder import edit_json
    from tests.data.industrial_builder import build_industrial
except ImportError:  # pytest's default import mode puts tests/data itself on sys.path
    from bop_builder import edit_json
    from industrial_builder import build_industrial

MINI = IndustrialSpec(
    name="mini",
    sensors=(Sensor("gcam", ("gray",), (40, 30)), Sensor("ccam", ("rgb",), (64, 48)),
             Sensor("dcam", ("gray", "depth"), (48, 36))),
    eval_modality="gray",
    obj_ids=(1, 2, 3),
    symmetric_obj_ids=(1, 2),
)  # fmt: skip
KEYS = ["000001/i000000", "000001/i000001", "000002/i000001"]  # scene 2, image 0 has no target


@pytest.fixture(scope="module")
def mini(tmp_path_factory):
    return build_industrial(tmp_path_factory.mktemp("ind") / "mini", MINI)


@pytest.fixture(scope="module")
def big(tmp_path_factory):
    return build_industrial(
        tmp_path_factory.mktemp("ind") / "xyzibd", INDUSTRIAL["xyzibd"], obj_ids=(1, 4), masks=False
    )


@pytest.fixture()
def copy(mini, tmp_path):
    """A fresh copy of MINI's root for a test that breaks a file."""
    return Path(shutil.copytree(mini.root, tmp_path / "mini"))


# --- views, cameras, ground truth ------------------------------------------------------------------------------------


def test_one_scene_per_capture_with_every_sensor_as_a_view(mini):
    ds = open_industrial(mini.root, "test", spec=MINI)
    assert ds.scene_keys == KEYS and ds.name == "mini" and ds.eval_sensor == "gcam"
    assert [(s.name, s.image_size) for s in ds.sensors] == [("gcam", (40, 30)), ("ccam", (64, 48)), ("dcam", (48, 36))]
    assert ds.image_size == (40, 30) and not ds.has_depth  # the evaluated sensor's
    assert ds.scene_camera_name == "scene_camera_gcam.json" and ds.image_ids_on_disk("000002") == {0, 1}
    for key in KEYS:
        scene = ds.scene(key)
        sid, im = scene.scene_id, int(key[-6:])
        assert scene.im_ids == [im, VIEW_ID_STRIDE + im, 2 * VIEW_ID_STRIDE + im]
        assert [v.evaluated for v in scene.views] == [True, False, False]
        assert [v.im_id for v in scene.evaluated_views] == [im]
        for view, sensor in zip(scene.views, MINI.sensors, strict=True):
            assert view.sensor == sensor.name and (view.width, view.height) == sensor.image_size
            np.testing.assert_array_equal(view.K, mini.K[(sid, sensor.name, im)])
            np.testing.assert_array_equal(view.T_cam_world, mini.T_cam_world[(sid, sensor.name, im)])
            assert view.info["bop_im_id"] == im and view.info["modality"] == sensor.intensity
            assert view.rgb_path == mini.split_dir / sid / f"{sensor.intensity}_{sensor.name}" / f"{im:06d}.png"
            n_gt = len(mini.gt_order[(sid, sensor.name)])
            assert len(view.mask_paths) == len(view.mask_visib_paths) == n_gt
            assert view.mask_visib_paths[-1].parent.name == f"mask_visib_{sensor.name}"
        gray, rgb, depth = scene.views
        assert gray.depth_path is None and rgb.depth_path is None
        assert depth.depth_path == mini.split_dir / sid / "depth_dcam" / f"{im:06d}.png" and depth.depth_scale == 0.1


def test_bop24_targets_select_the_captures_and_tiff_images_read(mini, tmp_path):
    root = Path(shutil.copytree(mini.root, tmp_path / "mini"))
    (root / "test_targets_bop19.json").unlink()
    (root / "test_targets_bop24.json").write_text(
        json.dumps([{"scene_id": 1, "im_id": 1}, {"scene_id": 2, "im_id": 0}])
    )
    ds = open_industrial(root, "test", spec=MINI)
    assert ds.scene_keys == ["000001/i000001", "000002/i000000"]
    assert pickle.loads(pickle.dumps(ds)).scene("000002/i000000").im_ids == ds.scene("000002/i000000").im_ids
    tiff = build_industrial(tmp_path / "tif", replace(MINI, image_suffix=".tif"), n_scenes=1)
    scene = next(open_industrial(tiff.root, "test", spec=MINI).scenes())
    assert [v.rgb_path.suffix for v in scene.views] == [".tif"] * 3 and scene.views[1].info["modality"] == "rgb"


def test_gt_is_associated_across_sensors_with_each_sensors_visibility(mini):
    ds = open_industrial(mini.root, "test", spec=MINI)
    for key in KEYS:
        scene = ds.scene(key)
        sid, im = scene.scene_id, int(key[-6:])
        assert len(scene.gt) == 3
        for i, (obj_id, T_wm) in enumerate(mini.objects[sid]):
            g = next(g for g in scene.gt if np.allclose(g.T_world_model[:3, 3], T_wm[:3, 3], atol=0.05))
            assert g.obj_id == obj_id
            for k, sensor in enumerate(MINI.sensors):
                v, order = k * VIEW_ID_STRIDE + im, mini.gt_order[(sid, sensor.name)]
                if i not in order:  # dcam does not see the last object
                    assert v not in g.gt_ids and v not in g.visib_fract
                    continue
                gt_id = order.index(i)
                assert g.gt_ids[v] == gt_id and g.visib_fract[v] == mini.visib[(sid, sensor.name, im)][gt_id]
                stored = json.loads((mini.split_dir / sid / f"scene_gt_{sensor.name}.json").read_text())[str(im)][gt_id]
                expected = pose_from_bop(stored["cam_R_m2c"], stored["cam_t_m2c"])
                np.testing.assert_array_equal(g.T_cam_model[v], expected)  # as stored, per sensor
    assert ds.residuals["gt_max_mm"] < 0.05


def test_rows_and_ground_truth_are_the_evaluated_sensors_images_only(mini):
    ds = open_industrial(mini.root, "test", spec=MINI)
    scene = ds.scene("000001/i000001")
    estimate = SceneEstimate(scene.key, scene.scene_id, tuple(ObjectEstimate(g.obj_id, g.T_world_model, 0.9)
                                                              for g in scene.gt), 3.0)  # fmt: skip
    rows = scene_estimates_to_rows(scene, estimate)
    assert len(rows) == 3 and {(r.scene_id, r.im_id) for r in rows} == {(1, 1)}
    for row, g in zip(rows, scene.gt, strict=True):  # in the evaluated sensor's camera frame
        np.testing.assert_allclose(row.T_cam_model, scene.views[0].T_cam_world @ g.T_world_model, atol=1e-9)
    gt = collect_ground_truth(ds, progress=False)
    assert list(gt.images) == [(1, 0), (1, 1), (2, 1)]
    image = gt.images[(2, 1)]
    assert (image.width, image.height) == (40, 30) and image.depth_path is None
    assert [p.gt_id for p in image.instances] == [0, 1, 2]
    assert [p.visib_fract for p in image.instances] == mini.visib[("000002", "gcam", 1)]
    assert gt.image_on_disk(2, 0) and not gt.image_on_disk(2, VIEW_ID_STRIDE) and gt.scene_on_disk(2)


def test_scoring_the_ground_truth_scores_every_target_once(mini):
    from bop_cender.eval.scoring import score_results
    from bop_cender.eval.toolkit_constants import mspd_width

    ds = open_industrial(mini.root, "test", spec=MINI)
    rows = []
    for scene in ds.scenes():  # a perfect estimate: one row per object and evaluated image
        objects = tuple(ObjectEstimate(g.obj_id, g.T_world_model, 1.0) for g in scene.gt)
        rows += scene_estimates_to_rows(scene, SceneEstimate(scene.key, scene.scene_id, objects, 1.0))
    report = score_results(rows, ds, progress=False)
    assert report.scores["AR_MSSD"] == report.scores["AR_MSPD"] == 1.0 and report.scores["AR_VSD"] is None
    assert report.metadata.mspd_width == 40  # the evaluated sensor's width
    assert {name: mspd_width(name, "test", 1).value for name in INDUSTRIAL} == {"ipd": 2064, "xyzibd": 1440,
                                                                                 "itoddmv": 1280}  # fmt: skip


# --- by name, by --dataset bop, info ---------------------------------------------------------------------------------


def test_a_registered_name_and_bop_open_the_multi_sensor_split(big):
    for dataset in ("xyzibd", "bop"):
        ds = open_dataset(DatasetRequest(dataset, big.root))
        assert ds.name == "xyzibd" and ds.eval_sensor == "xyz" and ds.image_size == (1440, 1080) and ds.has_depth
        assert [s.name for s in ds.sensors] == ["xyz", "photoneo", "realsense"] and ds.scene_keys == KEYS
        scene = ds.scene(KEYS[0])
        assert [(v.width, v.height) for v in scene.views] == [(1440, 1080), (2064, 1544), (1280, 720)]
    with pytest.raises(ConfigError, match="--n-views is for single-sensor"):
        open_dataset(DatasetRequest("xyzibd", big.root, n_views=3))


def test_an_unnamed_multi_sensor_split_asks_for_its_name(mini, tmp_path):
    root = shutil.copytree(mini.root, tmp_path / "custom")
    with pytest.raises(ConfigError, match="which one is evaluated is unknown") as info:
        open_dataset(DatasetRequest("bop", root))
    assert info.value.field == "--dataset"


def test_info_describes_the_sensors_and_reports_a_wrong_sized_image(big, tmp_path, capsys):
    from bop_cender.cli import main

    assert main(["info", "--dataset", "xyzibd", "--data-root", str(big.root), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "sensors   xyz 1440x1080 gray, depth (evaluated: gray); photoneo 2064x1544 gray, depth; realsense" in out
    assert "checked 2 meshes, 18 images (headers): no problem found" in out
    root = Path(shutil.copytree(big.root, tmp_path / "xyzibd"))
    bad = root / "test" / "000002" / "rgb_realsense" / "000001.png"
    bad.write_bytes((root / "test" / "000002" / "gray_xyz" / "000001.png").read_bytes())  # gray, 1440x1080
    assert main(["info", "--dataset", "xyzibd", "--data-root", str(root), "--no-progress"]) == 2
    out = capsys.readouterr().out
    assert f"problem   {bad}: size: image is 1440x1080, expected 1280x720 (its sensor's image size)" in out


# --- bad input: one error naming the file and the field ----------------------------------------------------------------


def _error(root: Path, load: bool = False) -> DatasetError:
    with pytest.raises(DatasetError) as info:
        ds = open_industrial(root, "test", spec=MINI)
        if load:
            list(ds.scenes())
    return info.value


def test_a_sensors_camera_file_missing(copy):
    (copy / "test" / "000002" / "scene_camera_dcam.json").unlink()
    e = _error(copy)
    assert e.file == str(copy / "test" / "000002" / "scene_camera_dcam.json") and e.field == "sensor dcam"
    assert "camera file of sensor dcam missing" in e.message


def test_a_sensors_image_ids_disagree(copy):
    edit_json(copy / "test" / "000001" / "scene_camera_ccam.json", lambda c: c.pop("1"))
    e = _error(copy, load=True)
    assert e.file.endswith("scene_gt_ccam.json") and e.field == "image ids"  # its own files first
    edit_json(copy / "test" / "000001" / "scene_gt_ccam.json", lambda c: c.pop("1"))
    edit_json(copy / "test" / "000001" / "scene_gt_info_ccam.json", lambda c: c.pop("1"))
    e = _error(copy, load=True)
    assert e.file.endswith("scene_camera_ccam.json") and e.field == "image ids" and "missing 1" in e.message


def test_sizes_that_disagree_with_the_sensors(copy):
    from bop_cender.data.bop_io import write_image

    image = copy / "test" / "000001" / "rgb_ccam" / "000000.png"
    write_image(image, np.zeros((30, 40, 3), np.uint8))
    e = _error(copy)
    assert (e.file, e.field) == (str(image), "size") and "expected 64x48 for sensor ccam" in e.message


def test_a_gray_image_where_rgb_is_expected(copy):
    from bop_cender.data.bop_io import write_image

    image = copy / "test" / "000001" / "rgb_ccam" / "000000.png"
    write_image(image, np.zeros((48, 64), np.uint8))
    e = _error(copy)
    assert (e.file, e.field) == (str(image), "channels") and "1-channel image where rgb is expected" in e.message


@pytest.mark.parametrize("keep_K", [False, True])
def test_a_cam_model(copy, keep_K):
    path = copy / "test" / "000001" / "scene_camera_ccam.json"

    def to_model(content):
        entry = content["0"]
        entry["cam_model"] = {"projection_model_type": "CameraModelType.FISHEYE624", "projection_params": [1.0] * 15}
        if not keep_K:
            del entry["cam_K"]

    edit_json(path, to_model)
    e = _error(copy, load=True)
    assert (e.file, e.field) == (str(path), "0: cam_model")
    assert ("both cam_K and cam_model" if keep_K else "FISHEYE624) without cam_K") in e.message


def test_a_capture_without_world_poses(copy):
    path = copy / "test" / "000001" / "scene_camera_dcam.json"
    edit_json(path, lambda c: [c["1"].pop("cam_R_w2c"), c["1"].pop("cam_t_w2c")])
    e = _error(copy, load=True)
    assert (e.file, e.field) == (str(path), "1") and "sensors of one capture are related" in e.message


def test_an_image_folder_without_its_camera_file_a_sensor_and_an_object_outside_the_table(copy):
    shutil.copytree(copy / "test" / "000001" / "rgb_ccam", copy / "test" / "000001" / "rgb_extra")
    e = _error(copy)
    assert (e.file, e.field) == (str(copy / "test" / "000001" / "scene_camera_extra.json"), "sensor extra")
    shutil.rmtree(copy / "test" / "000001" / "rgb_extra")
    with pytest.raises(DatasetError, match=r"sensor dcam is not one of mini's sensors \(gcam, ccam\)") as info:
        open_industrial(copy, "test", spec=replace(MINI, sensors=MINI.sensors[:2]))
    assert info.value.field == "sensor" and info.value.file.endswith("000001/scene_camera_dcam.json")
    with pytest.raises(DatasetError, match=r"object\(s\) \[1, 2\] are not mini's") as info:
        open_industrial(copy, "test", spec=replace(MINI, obj_ids=(3,)))
    assert info.value.field == "obj_id" and info.value.file.endswith("models/models_info.json")


# --- the table and the official toolkit --------------------------------------------------------------------------------


def test_the_command_line_offers_the_registered_names():
    from bop_cender.cli.options import DATASET_CHOICES
    from bop_cender.eval.detection import MAX_ESTIMATES_PER_IMAGE, MAX_ESTIMATES_PER_IMAGE_BY_DATASET

    assert DATASET_CHOICES == DATASETS and set(INDUSTRIAL) <= set(DATASETS)
    for name, spec in INDUSTRIAL.items():
        cap = MAX_ESTIMATES_PER_IMAGE_BY_DATASET.get(name, MAX_ESTIMATES_PER_IMAGE)
        assert spec.max_estimates_per_image == cap


def _toolkit():
    """``(dataset_params, inout)`` of the toolkit in ``BOP_TOOLKIT_DIR``, else the importable one; else skip."""
    path = os.environ.get("BOP_TOOLKIT_DIR")
    if path and path not in sys.path:
        sys.path.insert(0, path)
    try:
        return importlib.import_module("bop_toolkit_lib.dataset_params"), importlib.import_module(
            "bop_toolkit_lib.inout"
        )
    except ImportError:
        pytest.skip("set BOP_TOOLKIT_DIR to a checkout of thodan/bop_toolkit to compare with its readers")


def test_the_table_is_the_toolkits():
    dataset_params, _ = _toolkit()
    for name, spec in INDUSTRIAL.items():
        split = dataset_params.get_split_params("/nowhere", name, "test")
        model = dataset_params.get_model_params("/nowhere", name)
        assert (split["eval_sensor"], split["eval_modality"]) == (spec.eval_sensor, spec.eval_modality)
        assert {s.name: list(s.modalities) for s in spec.sensors} == split["im_modalities"]
        for s in spec.sensors:
            assert dataset_params.get_im_size(split, spec.eval_modality, s.name) == s.image_size
            assert split[f"{s.intensity}_{s.name}_tpath"].endswith(spec.image_suffix)
        assert list(spec.obj_ids) == model["obj_ids"] and list(spec.symmetric_obj_ids) == model["symmetric_obj_ids"]


def test_the_reader_agrees_with_the_toolkits_readers(big):
    dataset_params, inout = _toolkit()
    split = dataset_params.get_split_params(str(big.root.parent), "xyzibd", "test")
    ds = open_dataset(DatasetRequest("xyzibd", big.root))
    keys = dataset_params.scene_tpaths_keys(split["eval_modality"], split["eval_sensor"], 1)
    assert split[keys["scene_camera_tpath"]].format(scene_id=1) == str(ds.split_dir / "000001" / ds.scene_camera_name)
    for key in ds.scene_keys:
        scene = ds.scene(key)
        scene_int, im = int(scene.scene_id), scene.info["bop_im_id"]
        for view in scene.views:
            sensor, modality = view.sensor, view.info["modality"]
            assert split[f"{modality}_{sensor}_tpath"].format(scene_id=scene_int, im_id=im) == str(view.rgb_path)
            assert split[f"depth_{sensor}_tpath"].format(scene_id=scene_int, im_id=im) == str(view.depth_path)
            assert dataset_params.get_im_size(split, modality, sensor) == (view.width, view.height)
            camera = inout.load_scene_camera(
                split[f"scene_camera_{modality}_{sensor}_tpath"].format(scene_id=scene_int)
            )
            np.testing.assert_array_equal(view.K, camera[im]["cam_K"])
            np.testing.assert_array_equal(view.T_cam_world[:3, :3], camera[im]["cam_R_w2c"])
            np.testing.assert_array_equal(view.T_cam_world[:3, 3:], camera[im]["cam_t_w2c"])
            assert view.depth_scale == camera[im]["depth_scale"]
            stored = inout.load_scene_gt(split[f"scene_gt_{modality}_{sensor}_tpath"].format(scene_id=scene_int))[im]
            info = inout.load_json(split[f"scene_gt_info_{modality}_{sensor}_tpath"].format(scene_id=scene_int),
                                   keys_to_int=True)[im]  # fmt: skip
            seen = {g.gt_ids[view.im_id]: g for g in scene.gt if view.im_id in g.gt_ids}
            assert sorted(seen) == list(range(len(stored)))
            for gt_id, entry in enumerate(stored):
                g = seen[gt_id]
                assert g.obj_id == entry["obj_id"] and g.visib_fract[view.im_id] == info[gt_id]["visib_fract"]
                np.testing.assert_array_equal(g.T_cam_model[view.im_id][:3, :3], entry["cam_R_m2c"])
                np.testing.assert_array_equal(g.T_cam_model[view.im_id][:3, 3:], entry["cam_t_m2c"])
