"""Tests of the DIMO loader against a hand-typed fixture and against seeded builder output."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest

from bop_cender.data.dimo import PAPER_SELECTION, DimoSelection, open_dimo
from bop_cender.data.registry import DatasetRequest, open_dataset
from bop_cender.errors import ConfigError, DatasetError, DatasetWarning

try:
    from tests.data.dimo_builder import SceneSpec, build_dimo, edit_json
except ImportError:  # pytest's default import mode puts tests/data itself on sys.path
    from dimo_builder import SceneSpec, build_dimo, edit_json

HAND = Path(__file__).resolve().parents[1] / "fixtures" / "dimo_hand"


def _T(R_rows: list[list[float]], t: list[float]) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R_rows
    T[:3, 3] = t
    return T


# Hand-computed values of tests/fixtures/dimo_hand (see its README).
R_DOWN = [[1, 0, 0], [0, -1, 0], [0, 0, -1]]  # camera looking down -z, x along world x
R_DOWN_TURNED = [[0, 1, 0], [1, 0, 0], [0, 0, -1]]  # same, turned 90 degrees about z
T_CAM_WORLD = {
    0: _T(R_DOWN, [0, 0, 500]),
    1: _T(R_DOWN, [0, -100, 500]),
    2: _T(R_DOWN_TURNED, [0, -100, 500]),
}
T_WORLD_CUBE = _T([[0, -1, 0], [1, 0, 0], [0, 0, 1]], [0, 0, 10])
T_WORLD_CARRIER = _T(np.eye(3).tolist(), [0, 0, -5])
K_HAND = np.array([[40.0, 0, 16], [0, 40, 16], [0, 0, 1]])


# --------------------------------------------------------------------------- hand-typed fixture


def test_hand_real_views_cameras_and_images():
    ds = open_dimo(HAND, "real")
    assert (ds.name, ds.split, ds.has_depth, ds.image_size) == ("dimo", "real", False, (32, 32))
    assert ds.scene_keys == ["000000"]
    scene = ds.scene("000000")
    assert (scene.dataset, scene.split, scene.scene_id) == ("dimo", "real", "000000")
    assert scene.im_ids == [0, 2]  # image 1 has viewpoint 1: not in the paper's selection
    for view in scene.views:
        np.testing.assert_array_equal(view.K, K_HAND)
        np.testing.assert_array_equal(view.T_cam_world, T_CAM_WORLD[view.im_id])
        assert (view.width, view.height) == (32, 32)
        assert view.rgb_path == HAND / "real_jaigo" / "000000" / "rgb" / f"{view.im_id:06d}.png"
    assert scene.view(2).info == {"light": 0, "carrier": 2, "parts": 1, "viewpoint": 2}
    assert scene.info == {"carrier": 2, "composition": 1, "variant": None}
    # The camera of view 2 sits at (100, 0, 500) in the world: the c2w translation typed in the file.
    np.testing.assert_array_equal(scene.view(2).T_world_cam[:3, 3], [100, 0, 500])


def test_hand_gt_and_models():
    ds = open_dimo(HAND, "real")
    scene = ds.scene("000000")
    assert [g.obj_id for g in scene.gt] == [1, 100]
    np.testing.assert_array_equal(scene.gt[0].T_world_model, T_WORLD_CUBE)
    np.testing.assert_array_equal(scene.gt[1].T_world_model, T_WORLD_CARRIER)
    assert dict(scene.gt[0].gt_ids) == {0: 0, 2: 0}
    assert dict(scene.gt[1].gt_ids) == {0: 1, 2: 1}
    assert ds.target_obj_ids == [1]
    assert ds.models[1].is_target and not ds.models[100].is_target
    assert set(ds.eval_models) == {1, 100}
    assert ds.models[1].symmetries_discrete == [[0, -1, 0, 0, 1, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]]
    np.testing.assert_array_equal(ds.models[100].center, [0, 0, 0])
    np.testing.assert_array_equal(ds.models[100].mesh.bounds, [[-100, -100, -5], [100, 100, 5]])
    assert ds.residuals["gt_max_mm"] == 0.0 and ds.residuals["gt_pairs"] == 6.0


def test_hand_sim_old_key_spelling_and_both_camera_poses():
    ds = open_dimo(HAND, "sim")
    assert ds.scene_keys == ["000000_00"]
    scene = ds.scene("000000_00")
    assert scene.im_ids == [0, 1]
    assert scene.view(1).info == {"light": 3, "carrier": 2, "parts": 1, "viewpoint": 2}
    np.testing.assert_array_equal(scene.view(0).T_cam_world, T_CAM_WORLD[0])
    np.testing.assert_array_equal(scene.view(1).T_cam_world, T_CAM_WORLD[2])
    assert scene.info["variant"] == 0
    assert ds.residuals["cam_pairs"] == 2.0 and ds.residuals["cam_max_mm"] == 0.0


def test_hand_selection_notes_and_everything():
    notes = "\n".join(open_dimo(HAND, "real").selection)
    assert "1 viewpoint not selected" in notes
    assert "viewpoints 0, 2" in notes
    assert "2 of 3" in notes
    assert "no models_eval" in notes
    everything = open_dimo(HAND, "real", DimoSelection.everything())
    assert everything.scene("000000").im_ids == [0, 1, 2]
    np.testing.assert_array_equal(everything.scene("000000").view(1).T_cam_world, T_CAM_WORLD[1])


def test_hand_train_split_has_no_folders():
    with pytest.raises(DatasetError) as exc:
        open_dimo(HAND, "train")
    assert "sim_jaigo" in str(exc.value) and "1 variant not in split train" in str(exc.value)


def test_registry_opens_dimo():
    ds = open_dataset(DatasetRequest("dimo", HAND, "real"))
    assert ds.scene_keys == ["000000"] and ds.name == "dimo"


def test_unknown_split_is_a_config_error():
    with pytest.raises(ConfigError) as exc:
        open_dimo(HAND, "test")
    assert exc.value.field == "--split"
    assert "real, sim, train" in str(exc.value)


def test_paper_selection_values():
    assert PAPER_SELECTION.camera == "jaigo" and PAPER_SELECTION.carrier == 2
    assert PAPER_SELECTION.compositions == (1, 2, 4)
    assert PAPER_SELECTION.viewpoints == (0, 2, 4, 6, 8, 10, 12)
    assert PAPER_SELECTION.sim_variants == (0,)
    assert PAPER_SELECTION.train_variants == tuple(range(16, 71))


# --------------------------------------------------------------------------- builder fixtures


def test_suffix_folders_sort_and_split_membership(tmp_path):
    sim = ["000000", "000000_00", "000000_03", "000000_17", "000000_40", "000010_70", "000002_00"]
    specs = [SceneSpec(name, camera_dir="sim_jaigo", viewpoints=(0, 2)) for name in sim]
    specs += [SceneSpec(name, viewpoints=(0, 2)) for name in ("000001", "000000_00", "000000")]
    build_dimo(tmp_path, specs)
    (tmp_path / "sim_jaigo" / "notes").mkdir()
    (tmp_path / "sim_jaigo" / "README.txt").write_text("not a folder")

    assert open_dimo(tmp_path, "real").scene_keys == ["000000", "000001"]
    sim_ds = open_dimo(tmp_path, "sim")
    assert sim_ds.scene_keys == ["000000_00", "000002_00"]
    notes = "\n".join(sim_ds.selection)
    assert "8 found in sim_jaigo/, 2 kept" in notes
    assert "4 variant not in split sim" in notes
    assert "1 no variant suffix" in notes and "1 not a scene folder name" in notes
    assert open_dimo(tmp_path, "train").scene_keys == ["000000_17", "000000_40", "000010_70"]
    everything = open_dimo(tmp_path, "sim", DimoSelection.everything())
    assert everything.scene_keys == ["000000_00", "000000_03", "000000_17", "000000_40", "000002_00", "000010_70"]
    assert "1 variant folder" in "\n".join(open_dimo(tmp_path, "real").selection)
    scene = open_dimo(tmp_path, "train").scene("000000_17")
    assert scene.scene_id == "000000_17" and scene.info["variant"] == 17


def test_selection_drops_other_carrier_and_composition(tmp_path):
    specs = [
        SceneSpec("000000", viewpoints=(0, 1, 2, 3, 4)),
        SceneSpec("000001", carrier=1),
        SceneSpec("000002", parts=3),
        SceneSpec("000003", parts=4, viewpoints=(1, 3)),
    ]
    build_dimo(tmp_path, specs)
    ds = open_dimo(tmp_path, "real")
    assert ds.scene_keys == ["000000"]
    assert ds.scene("000000").im_ids == [0, 2, 4]
    notes = "\n".join(ds.selection)
    for phrase in (
        "1 other carrier",
        "1 other composition",
        "1 viewpoint not selected",
        "3 of 5",
        "viewpoints 0, 2, 4",
    ):
        assert phrase in notes


@pytest.mark.parametrize("camera_keys", ["c2w", "w2c", "both"])
def test_camera_key_variants(tmp_path, camera_keys):
    truth = build_dimo(tmp_path, [SceneSpec("000000", camera_keys=camera_keys)])["000000"]
    ds = open_dimo(tmp_path, "real", DimoSelection.everything())
    scene = ds.scene("000000")
    for view in scene.views:
        np.testing.assert_allclose(view.T_cam_world, np.linalg.inv(truth.T_world_cam[view.im_id]), atol=1e-9)
    assert ds.residuals["cam_pairs"] == (3.0 if camera_keys == "both" else 0.0)
    assert ds.residuals["cam_max_mm"] < 1e-9


def test_carrier_is_occluder_never_target(tmp_path):
    build_dimo(tmp_path, [SceneSpec("000000")])
    ds = open_dimo(tmp_path, "real")
    assert ds.target_obj_ids == [1, 2]
    assert not ds.models[100].is_target
    assert [g.obj_id for g in ds.scene("000000").gt] == [1, 2, 100]


def test_old_info_keys_with_string_values(tmp_path):
    build_dimo(tmp_path, [SceneSpec("000000", old_info_keys=True, parts=2, light=5)])
    scene = open_dimo(tmp_path, "real").scene("000000")
    assert scene.im_ids == [0, 2]
    assert scene.view(0).info == {"light": 5, "carrier": 2, "parts": 2, "viewpoint": 0}
    assert scene.info == {"carrier": 2, "composition": 2, "variant": None}


def test_round_trip_world_camera_world(tmp_path):
    truths = build_dimo(tmp_path, [SceneSpec("000000", viewpoints=(0, 2, 4)), SceneSpec("000001", viewpoints=(2, 4))])
    ds = open_dimo(tmp_path, "real")
    for scene in ds.scenes():
        truth = truths[scene.scene_id]
        for view in scene.views:
            for gt, (obj_id, T_world_model) in zip(scene.gt, truth.objects, strict=True):
                assert gt.obj_id == obj_id
                T_cam_model = view.T_cam_world @ gt.T_world_model
                expected = np.linalg.inv(truth.T_world_cam[view.im_id]) @ T_world_model
                np.testing.assert_allclose(T_cam_model, expected, atol=1e-9)
                np.testing.assert_allclose(view.T_world_cam @ T_cam_model, T_world_model, atol=1e-9)
    # Viewpoint 2 is one fixed camera pose in both scenes.
    np.testing.assert_allclose(ds.scene("000000").view(1).T_cam_world, ds.scene("000001").view(0).T_cam_world)
    assert ds.residuals["gt_max_mm"] < 1e-9 and ds.residuals["gt_pairs"] == 3 * 3 + 2 * 3


# --------------------------------------------------------------------------- bad input


@pytest.fixture
def scene_dir(tmp_path) -> Path:
    """One real scene, three images (viewpoints 0, 2, 4), objects 1, 2 and 100; c2w and w2c."""
    build_dimo(tmp_path, [SceneSpec("000000", viewpoints=(0, 2, 4))])
    return tmp_path / "real_jaigo" / "000000"


def _load_error(scene_dir: Path) -> DatasetError:
    with pytest.raises(DatasetError) as exc:
        open_dimo(scene_dir.parents[1], "real").scene("000000")
    return exc.value


def _assert_names(err: DatasetError, file: str, field: str | None, *phrases: str) -> None:
    text = str(err)
    assert Path(err.file).name == file or err.file.endswith(file), text
    assert err.field == field, text
    assert file in text and (field is None or field in text), text
    for phrase in phrases:
        assert phrase in text, text


def test_missing_scene_gt(scene_dir):
    (scene_dir / "scene_gt.json").unlink()
    _assert_names(_load_error(scene_dir), "scene_gt.json", None, "file not found")


def test_malformed_json(scene_dir):
    (scene_dir / "scene_camera.json").write_text('{"0": {"cam_K": [1, 2,')
    _assert_names(_load_error(scene_dir), "scene_camera.json", None, "malformed JSON", "line 1")


def test_image_ids_differ_between_files(scene_dir):
    edit_json(scene_dir / "scene_gt.json", lambda d: d.pop("1"))
    _assert_names(_load_error(scene_dir), "scene_gt.json", "image ids", "scene_camera.json", "missing 1")


def test_scene_info_lacks_an_image(scene_dir):
    edit_json(scene_dir / "scene_info.json", lambda d: d.pop("2"))
    _assert_names(_load_error(scene_dir), "scene_info.json", "image ids", "missing 2")


def test_unknown_obj_id(scene_dir):
    def set_7(data):
        data[0]["obj_id"] = 7

    edit_json(scene_dir / "scene_gt_world.json", set_7)
    _assert_names(_load_error(scene_dir), "scene_gt_world.json", "[0].obj_id", "object 7", "models_info.json")


def test_scene_gt_order_differs_from_world(scene_dir):
    edit_json(scene_dir / "scene_gt.json", lambda d: d["1"].reverse())
    _assert_names(_load_error(scene_dir), "scene_gt.json", "1[0].obj_id", "expected obj_id 1", "got 100")


def test_scene_gt_length_differs_from_world(scene_dir):
    edit_json(scene_dir / "scene_gt.json", lambda d: d["2"].pop())
    _assert_names(_load_error(scene_dir), "scene_gt.json", "2", "expected 3 entries", "got 2")


def test_obj_id_as_string(scene_dir):
    def stringify(data):
        data["0"][1]["obj_id"] = "2"

    edit_json(scene_dir / "scene_gt.json", stringify)
    _assert_names(_load_error(scene_dir), "scene_gt.json", "0[1].obj_id", "integer object id")


def test_non_orthonormal_rotation(scene_dir):
    def scale(data):
        data["0"]["cam_R_c2w"] = [1.1 * x for x in data["0"]["cam_R_c2w"]]

    edit_json(scene_dir / "scene_camera.json", scale)
    _assert_names(_load_error(scene_dir), "scene_camera.json", "0.cam_R_c2w", "not orthonormal")


def test_nan_in_a_pose(scene_dir):
    def nan(data):
        data[1]["cam_t_m2w"][2] = math.nan

    edit_json(scene_dir / "scene_gt_world.json", nan)
    _assert_names(_load_error(scene_dir), "scene_gt_world.json", "[1].cam_t_m2w", "finite")


def test_wrong_length_intrinsics(scene_dir):
    edit_json(scene_dir / "scene_camera.json", lambda d: d["1"]["cam_K"].pop())
    _assert_names(_load_error(scene_dir), "scene_camera.json", "1.cam_K", "shape (9,)")


def test_rotation_without_translation(scene_dir):
    edit_json(scene_dir / "scene_camera.json", lambda d: d["0"].pop("cam_t_c2w"))
    _assert_names(_load_error(scene_dir), "scene_camera.json", "0.cam_t_c2w", "cam_R_c2w")


def test_no_camera_pose(scene_dir):
    def strip(data):
        for key in ("cam_R_c2w", "cam_t_c2w", "cam_R_w2c", "cam_t_w2c"):
            data["2"].pop(key)

    edit_json(scene_dir / "scene_camera.json", strip)
    _assert_names(_load_error(scene_dir), "scene_camera.json", "2", "missing camera pose")


def test_c2w_and_w2c_disagree(scene_dir):
    def shift(data):
        data["1"]["cam_t_w2c"][0] += 50.0

    edit_json(scene_dir / "scene_camera.json", shift)
    _assert_names(_load_error(scene_dir), "scene_camera.json", "1.cam_R_w2c/cam_t_w2c", "50.000 mm")


def test_scene_gt_with_inverted_camera_is_a_frame_mixup(tmp_path):
    truth = build_dimo(tmp_path, [SceneSpec("000000")])["000000"]

    def mixup(data):  # T_m2c written as T_c2w @ T_m2w instead of inv(T_c2w) @ T_m2w
        for im_id, entries in data.items():
            for entry, (_, T_wm) in zip(entries, truth.objects, strict=True):
                T = truth.T_world_cam[int(im_id)] @ T_wm
                entry["cam_R_m2c"], entry["cam_t_m2c"] = T[:3, :3].ravel().tolist(), T[:3, 3].tolist()

    edit_json(truth.scene_dir / "scene_gt.json", mixup)
    _assert_names(_load_error(truth.scene_dir), "scene_gt.json", "0[0]", "frame mix-up")


def test_half_millimetre_rounding_warns(scene_dir):
    def nudge(data):
        data["2"][1]["cam_t_m2c"][0] += 0.5

    edit_json(scene_dir / "scene_gt.json", nudge)
    ds = open_dimo(scene_dir.parents[1], "real")
    with pytest.warns(DatasetWarning, match=r"0\.500 mm") as record:
        ds.scene("000000")
    assert any("scene_gt.json: 2[1]" in str(w.message) for w in record)
    assert ds.residuals["gt_max_mm"] == pytest.approx(0.5, abs=1e-6)


def test_consistent_scene_does_not_warn(scene_dir):
    with warnings.catch_warnings():
        warnings.simplefilter("error", DatasetWarning)
        open_dimo(scene_dir.parents[1], "real").scene("000000")


def test_missing_rgb(scene_dir):
    (scene_dir / "rgb" / "000001.png").unlink()
    _assert_names(_load_error(scene_dir), "000001.png", None, "image not found", "rgb")


def test_scene_info_missing_key_at_open(scene_dir):
    edit_json(scene_dir / "scene_info.json", lambda d: d["0"].pop("carrier"))
    with pytest.raises(DatasetError) as exc:
        open_dimo(scene_dir.parents[1], "real")
    _assert_names(exc.value, "scene_info.json", "0.carrier", "'carrier_id'")


def test_scene_info_non_numeric_value(scene_dir):
    edit_json(scene_dir / "scene_info.json", lambda d: d["1"].update(viewpoint="two"))
    with pytest.raises(DatasetError) as exc:
        open_dimo(scene_dir.parents[1], "real")
    _assert_names(exc.value, "scene_info.json", "1.viewpoint", "expected an integer")


def test_missing_camera_folder(tmp_path):
    build_dimo(tmp_path, [SceneSpec("000000")])
    with pytest.raises(DatasetError) as exc:
        open_dimo(tmp_path, "sim")
    assert exc.value.file.endswith("sim_jaigo") and "camera folder not found" in str(exc.value)


@pytest.mark.parametrize(("option", "value"), [("model_type", "eval"), ("n_views", 3)])
def test_registry_refuses_bop_only_options_on_dimo(option, value):
    with pytest.raises(ConfigError) as exc:
        open_dataset(DatasetRequest("dimo", HAND, "real", **{option: value}))
    assert exc.value.field == "--" + option.replace("_", "-")
    assert "DIMO" in str(exc.value)


def test_a_models_eval_folder_is_said_to_be_unread(tmp_path):
    """bop-cender synth writes one beside models/; the note said DIMO had none, and a different one went unnoticed."""
    import shutil

    root = shutil.copytree(HAND, tmp_path / "dimo")
    shutil.copytree(root / "models", root / "models_eval")
    notes = "\n".join(open_dimo(root, "real").selection)
    assert "models_eval/ is not part of DIMO's layout and is not read: evaluation uses the models/ meshes" in notes
