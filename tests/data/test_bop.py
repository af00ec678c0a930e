"""The generic BOP loader on seeded mini datasets written by ``bop_builder``."""

import json
import math
import pickle
import re
import shutil
import warnings

import numpy as np
import pytest

from bop_cender.data.bop import group_views, open_bop
from bop_cender.data.registry import DatasetRequest, open_dataset
from bop_cender.errors import ConfigError, DatasetError, DatasetWarning
from bop_cender.geometry.poses import pose_from_bop, pose_residual

try:
    from tests.data.bop_builder import BopSpec, build_bop, edit_json
except ImportError:  # pytest's default import mode puts tests/data itself on sys.path
    from bop_builder import BopSpec, build_bop, edit_json

SMALL = BopSpec(n_scenes=1, n_images=4, pbr_scenes=0, target_fraction=1.0)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    return build_bop(tmp_path_factory.mktemp("mini") / "minibop")


def _groups(ds) -> dict[str, list[list[int]]]:
    out: dict[str, list[list[int]]] = {}
    for scene in ds.scenes():
        out.setdefault(scene.scene_id, []).append(scene.im_ids)
    return out


def _load_all(ds) -> None:
    for _ in ds.scenes():
        pass


# --- opening: split folders, names, models ---------------------------------------------------


def test_split_resolution_and_name(built):
    ds = open_bop(built.root, "test")
    assert ds.name == "minibop" and ds.split == "test"
    assert ds.scene_keys[0] == "000001/g00"
    assert any("folder test_primesense/" in n for n in ds.selection)
    for kwargs in ({"split": "test_primesense"}, {"split": "test", "split_type": "primesense"}):
        assert open_bop(built.root, name="tless", **kwargs).scene_keys == ds.scene_keys
    assert open_bop(built.root, "test", name="tless").name == "tless"
    assert ds.image_size == (32, 24) and ds.has_depth
    assert sorted(ds.models) == [1, 2, 3]
    assert ds.eval_models[1].path.parent.name == "models_eval"
    assert ds.models[1].symmetries_continuous and ds.models[2].symmetries_discrete


def test_unknown_split_lists_the_split_folders(built):
    with pytest.raises(ConfigError, match=r"unknown split 'val'.*test_primesense.*train_pbr"):
        open_bop(built.root, "val")
    with pytest.raises(ConfigError, match=r"test_kinect/ not found"):
        open_bop(built.root, "test", split_type="kinect")


def test_ambiguous_split_needs_a_type(tmp_path):
    root = build_bop(tmp_path / "d", SMALL, split_folder="train_primesense").root
    shutil.copytree(root / "train_primesense", root / "train_kinect")
    with pytest.raises(ConfigError, match="ambiguous"):
        open_bop(root, "train")
    assert open_bop(root, "train", split_type="kinect").selection[0] == "split 'train': folder train_kinect/"


def test_models_folder_choice(tmp_path):
    root = build_bop(tmp_path / "d", SMALL, models_dirs=("models_cad",)).root
    with pytest.raises(ConfigError, match=r"models/ not found; models folders: \['models_cad'\]"):
        open_bop(root, "test")
    ds = open_bop(root, "test", model_type="cad")
    assert ds.models[1].path.parent.name == "models_cad"
    assert ds.eval_models is ds.models
    assert any("no separate models_eval/" in n for n in ds.selection)


def test_a_model_without_an_evaluation_model_is_refused(tmp_path):
    """Scoring reads every shown object's evaluation model (diameter, symmetries): one missing is one error naming
    models_eval/models_info.json when the dataset opens, not a KeyError in the middle of `score`."""
    root = build_bop(tmp_path / "d", SMALL).root
    info = json.loads((root / "models_eval" / "models_info.json").read_text())
    del info["2"]
    (root / "models_eval" / "models_info.json").write_text(json.dumps(info))
    with pytest.raises(DatasetError, match=r"models_eval/models_info.json: object\(s\) \[2\] of models/ have no"):
        open_bop(root, "test")


def test_registry_opens_bop(built):
    ds = open_dataset(DatasetRequest("bop", built.root, "test"))
    assert ds.scene_keys == open_bop(built.root, "test").scene_keys
    assert open_dataset(DatasetRequest("bop", built.root)).split == "test"


@pytest.mark.parametrize("n_views", [0, -1, 2.5])
def test_bad_n_views(built, n_views):
    with pytest.raises(ConfigError, match="--n-views: expected a positive integer"):
        open_bop(built.root, "test", n_views=n_views)


# --- grouping ---------------------------------------------------------------------------------


@pytest.mark.parametrize("n_views", [1, 2, 3, 5, 10])
def test_every_target_image_in_exactly_one_group(built, n_views):
    ds = open_bop(built.root, "test", n_views=n_views)
    groups = _groups(ds)
    assert sorted(groups) == sorted(built.target_images)
    for scene_id, scene_groups in groups.items():
        assert sorted(im for g in scene_groups for im in g) == built.target_images[scene_id]
        sizes = [len(g) for g in scene_groups]
        assert all(s == n_views for s in sizes[:-1]) and 1 <= sizes[-1] <= n_views
        assert sizes[-1] == len(built.target_images[scene_id]) - n_views * (len(sizes) - 1)
    assert any(
        "BOP'19 targets" in n and f"{sum(map(len, built.target_images.values()))} images" in n for n in ds.selection
    )


def test_grouping_is_deterministic_per_seed(built):
    a = _groups(open_bop(built.root, "test", n_views=2, seed=0))
    assert a == _groups(open_bop(built.root, "test", n_views=2, seed=0))
    assert a != _groups(open_bop(built.root, "test", n_views=2, seed=1))


def test_group_views_depends_on_seed_and_scene_only():
    ids = [9, 3, 14, 0, 7, 21, 5]
    groups = group_views(ids, 3, seed=4, scene_int=2)
    assert [len(g) for g in groups] == [3, 3, 1]
    assert sorted(im for g in groups for im in g) == sorted(ids)
    assert all(g == sorted(g) for g in groups)
    assert group_views(list(reversed(ids)), 3, seed=4, scene_int=2) == groups  # input order is irrelevant
    others = [group_views(ids, 3, seed=4, scene_int=s) for s in range(3, 8)]
    assert any(o != groups for o in others)


def test_without_targets_every_image_is_used(tmp_path):
    root = build_bop(tmp_path / "d", SMALL, with_targets=False).root
    ds = open_bop(root, "test", n_views=3)
    groups = _groups(ds)
    assert list(groups) == ["000001"] and [len(g) for g in groups["000001"]] == [3, 1]
    assert sorted(im for g in groups["000001"] for im in g) == [0, 1, 2, 3]
    assert any("no test_targets_bop19.json" in n for n in ds.selection)


def test_pbr_one_image_per_scene(built):
    ds = open_bop(built.root, "train_pbr", n_views=2)
    spec = built.spec
    assert ds.scene_keys == [f"{s:06d}/i{im:06d}" for s in range(spec.pbr_scenes) for im in range(spec.pbr_images)]
    for scene in ds.scenes():
        (view,) = scene.views
        assert view.rgb_path.suffix == ".jpg"
        truth = built.pbr_objects[(scene.scene_id, view.im_id)]
        assert len(scene.gt) == len(truth)
        for gt in scene.gt:
            # objects are re-dropped per image: each image's world poses are its own
            assert min(pose_residual(gt.T_world_model, T)[0] for o, T in truth if o == gt.obj_id) < 0.05


def test_images_without_w2c_are_single_view_scenes(tmp_path):
    built = build_bop(tmp_path / "d", BopSpec(n_scenes=2, n_images=4, pbr_scenes=0, target_fraction=1.0))

    def drop(cams):
        del cams["2"]["cam_R_w2c"], cams["2"]["cam_t_w2c"]

    edit_json(built.split_dir / "000002" / "scene_camera.json", drop)
    ds = open_bop(built.root, "test", n_views=2)
    assert [k for k in ds.scene_keys if k.startswith("000002")] == [f"000002/i{im:06d}" for im in range(4)]
    assert [k for k in ds.scene_keys if k.startswith("000001")] == ["000001/g00", "000001/g01"]
    assert any("000002" in n and "its own Scene" in n for n in ds.selection)
    scene = ds.scene("000002/i000002")
    np.testing.assert_array_equal(scene.views[0].T_cam_world, np.eye(4))
    assert "world_frame" in scene.info
    gts = json.loads((built.split_dir / "000002" / "scene_gt.json").read_text())["2"]
    for gt in scene.gt:  # world frame = camera frame
        e = gts[gt.gt_ids[2]]
        np.testing.assert_allclose(gt.T_world_model, pose_from_bop(e["cam_R_m2c"], e["cam_t_m2c"]))


# --- GT: world poses, association, round trip ------------------------------------------------


def test_round_trip_world_poses_reproduce_scene_gt(built):
    ds = open_bop(built.root, "test", n_views=3)
    n_pairs = 0
    for scene in ds.scenes():
        gts = json.loads((built.split_dir / scene.scene_id / "scene_gt.json").read_text())
        truth = built.world_objects[scene.scene_id]
        assert sorted(g.obj_id for g in scene.gt) == sorted(o for o, _ in truth)
        for gt in scene.gt:
            assert sorted(gt.gt_ids) == scene.im_ids  # every instance is listed in every image
            for im, gt_id in gt.gt_ids.items():
                e = gts[str(im)][gt_id]
                assert e["obj_id"] == gt.obj_id
                dt, dr = pose_residual(
                    scene.view(im).T_cam_world @ gt.T_world_model, pose_from_bop(e["cam_R_m2c"], e["cam_t_m2c"])
                )
                assert dt < 0.02 and dr < 1e-5
                n_pairs += 1
            # and the world pose is the one the files were written from, up to the files' rounding
            assert min(pose_residual(gt.T_world_model, T)[0] for o, T in truth if o == gt.obj_id) < 0.05
            assert set(gt.visib_fract) == set(gt.gt_ids)
    assert n_pairs > 0
    assert 0 < ds.residuals["gt_max_mm"] < 0.1 and ds.residuals["gt_max_rad"] < 1e-4


def test_association_does_not_rely_on_list_order(tmp_path):
    built = build_bop(tmp_path / "d", SMALL)
    ds0 = open_bop(built.root, "test", n_views=4)
    before = {(g.obj_id, tuple(np.round(g.T_world_model[:3, 3], 3))): g.gt_ids for g in ds0.scene("000001/g00").gt}
    order = [3, 1, 0, 2]
    for name in ("scene_gt.json", "scene_gt_info.json"):
        edit_json(built.split_dir / "000001" / name, lambda d: d.update({"0": [d["0"][i] for i in order]}))
    after = open_bop(built.root, "test", n_views=4).scene("000001/g00").gt
    assert len(after) == len(before) == SMALL.n_instances
    for g in after:
        old = before[(g.obj_id, tuple(np.round(g.T_world_model[:3, 3], 3)))]
        assert g.gt_ids[0] == order.index(old[0]) and all(g.gt_ids[im] == old[im] for im in (1, 2, 3))


def test_views_carry_per_image_intrinsics_and_files(built):
    scene = open_bop(built.root, "test", n_views=5).scene("000001/g00")
    cams = json.loads((built.split_dir / "000001" / "scene_camera.json").read_text())
    Ks = [v.K for v in scene.views]
    assert any(not np.allclose(Ks[0], K) for K in Ks[1:])
    for v in scene.views:
        np.testing.assert_array_equal(v.K.ravel(), cams[str(v.im_id)]["cam_K"])
        np.testing.assert_allclose(v.T_cam_world, built.T_cam_world["000001"][v.im_id])
        assert (v.width, v.height) == (32, 24) and v.depth_scale == 0.1
        assert v.info == {"elev": 60, "mode": 0}
        assert v.rgb_path.name == f"{v.im_id:06d}.png" and v.depth_path.is_file()
        assert [p.name for p in v.mask_visib_paths] == [f"{v.im_id:06d}_{g:06d}.png" for g in range(4)]


def test_rounding_is_fine_half_a_millimetre_warns(tmp_path):
    built = build_bop(tmp_path / "d", SMALL)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DatasetWarning)
        _load_all(open_bop(built.root, "test"))  # T-LESS rounding: 0.01 mm, 1e-6
    edit_json(
        built.split_dir / "000001" / "scene_gt.json",
        lambda d: d["2"][1]["cam_t_m2c"].__setitem__(0, d["2"][1]["cam_t_m2c"][0] + 0.5),
    )
    ds = open_bop(built.root, "test")
    with pytest.warns(DatasetWarning, match=r"0\.[45]\d\d mm .*scene_gt\.json: 2\[1\]"):
        _load_all(ds)
    assert ds.residuals["gt_max_mm"] == pytest.approx(0.5, abs=0.02)


def test_depth_scale_falls_back_to_the_camera_file(tmp_path):
    built = build_bop(tmp_path / "d", SMALL)
    edit_json(built.split_dir / "000001" / CAM, lambda d: [e.pop("depth_scale") for e in d.values()])
    edit_json(built.root / "camera_primesense.json", lambda c: c.update(depth_scale=0.25))
    assert open_bop(built.root, "test").scene("000001/g00").views[0].depth_scale == 0.25
    edit_json(built.root / "camera_primesense.json", lambda c: c.pop("depth_scale"))
    with pytest.raises(
        DatasetError, match=r"scene_camera\.json: \d: missing key 'depth_scale' \(needed for \d+\.png\)"
    ):
        open_bop(built.root, "test").scene("000001/g00")


def test_dataset_pickles_with_its_loader(built):
    ds = open_bop(built.root, "test")
    scene = ds.scene(ds.scene_keys[1])
    again = pickle.loads(pickle.dumps(ds))
    again._cache.clear()
    reloaded = again.scene(ds.scene_keys[1])
    assert reloaded.im_ids == scene.im_ids
    np.testing.assert_array_equal(reloaded.gt[0].T_world_model, scene.gt[0].T_world_model)


def test_declared_size_checked_against_the_images(tmp_path):
    built = build_bop(tmp_path / "d", SMALL)
    edit_json(built.root / "camera_primesense.json", lambda c: c.update(width=64, height=48))
    with pytest.warns(DatasetWarning, match="says 64x48 but .* is 32x24"):
        ds = open_bop(built.root, "test")
    assert ds.image_size == (32, 24)


# --- bad input --------------------------------------------------------------------------------


def _shift_image_t(d, im: str, mm: float):
    for e in d[im]:
        e["cam_t_m2c"][0] += mm


def _set(key, value):
    return lambda d: d["1"].__setitem__(key, value)


CAM, GT, INFO, TARGETS = "scene_camera.json", "scene_gt.json", "scene_gt_info.json", "test_targets_bop19.json"

BAD_CASES = {
    "missing scene_gt": (GT, None, r"scene_gt\.json: file not found"),
    "malformed json": (INFO, "{", r"scene_gt_info\.json: malformed JSON"),
    "image ids differ": (GT, lambda d: d.pop("2"), r"scene_gt\.json: image ids: .*missing 2"),
    "unknown obj_id": (GT, lambda d: d["1"][0].update(obj_id=99), r"scene_gt\.json: 1\[0\]\.obj_id: unknown object 99"),
    "non-orthonormal R": (
        CAM,
        lambda d: d["1"].update(cam_R_w2c=[1.1 * x for x in d["1"]["cam_R_w2c"]]),
        r"scene_camera\.json: 1: cam_R_w2c/cam_t_w2c: rotation is not orthonormal",
    ),
    "NaN": (GT, lambda d: d["1"][0]["cam_t_m2c"].__setitem__(0, math.nan), r"1\[0\]\.cam_t_m2c: expected finite"),
    "cam_K of 8": (
        CAM,
        lambda d: d["1"].update(cam_K=d["1"]["cam_K"][:8]),
        r"scene_camera\.json: 1: cam_K: expected shape \(9,\)",
    ),
    "gt_info length": (INFO, lambda d: d["1"].pop(), r"scene_gt_info\.json: 1: expected a list of 4 entries"),
    "depth_scale": (CAM, _set("depth_scale", -0.1), r"1: depth_scale: expected a positive depth_scale"),
    "half w2c": (CAM, lambda d: d["1"].pop("cam_t_w2c"), r"scene_camera\.json: 1: cam_R_w2c and cam_t_w2c"),
    "frame mix-up 100 mm": (
        GT,
        lambda d: _shift_image_t(d, "2", 100.0),
        r"scene_gt\.json: 2\[\d\]: pose inconsistent.*100\.0",
    ),
    "rotated 0.05 rad": (
        GT,
        lambda d: d["3"][2].update(cam_R_m2c=(np.reshape(d["3"][2]["cam_R_m2c"], (3, 3)) @ _rz(0.05)).ravel().tolist()),
        r"scene_gt\.json: 3\[2\]: pose inconsistent.*0\.0500 rad",
    ),
    "target image unknown": (
        TARGETS,
        lambda d: d.append({"im_id": 99, "inst_count": 1, "obj_id": 1, "scene_id": 1}),
        r"test_targets_bop19\.json: \[\d+\]\.im_id: image 99 is not in",
    ),
    "target scene unknown": (
        TARGETS,
        lambda d: d.append({"im_id": 0, "inst_count": 1, "obj_id": 1, "scene_id": 7}),
        r"test_targets_bop19\.json: \[\d+\]\.scene_id: scene 7 has no folder",
    ),
    "targets empty": (TARGETS, lambda d: d.clear(), r"test_targets_bop19\.json: expected a non-empty list of targets"),
    "target object unknown": (
        TARGETS,
        lambda d: d.append({"im_id": 0, "inst_count": 1, "obj_id": 42, "scene_id": 1}),
        r"\.obj_id: object 42 is not in the models",
    ),
}


def _rz(a: float) -> np.ndarray:
    return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])


@pytest.mark.parametrize("case", list(BAD_CASES))
def test_bad_input_raises_a_dataset_error_naming_file_and_field(tmp_path, case):
    built = build_bop(tmp_path / "d", SMALL)
    name, edit, pattern = BAD_CASES[case]
    path = built.root / name if name == TARGETS else built.split_dir / "000001" / name
    if edit is None:
        path.unlink()
    elif isinstance(edit, str):
        path.write_text(edit)
    else:
        edit_json(path, edit)
    with pytest.raises(DatasetError, match=pattern):
        _load_all(open_bop(built.root, "test", n_views=4))


@pytest.mark.parametrize("sub", ["rgb", "depth", "mask", "mask_visib"])
def test_missing_image_file_is_named(tmp_path, sub):
    built = build_bop(tmp_path / "d", SMALL)
    victim = sorted((built.split_dir / "000001" / sub).iterdir())[-1]
    victim.unlink()
    with pytest.raises(DatasetError, match=re.escape(str(victim.parent)) + "[:/]"):
        _load_all(open_bop(built.root, "test", n_views=4))


def test_stray_folder_in_split_is_an_error(tmp_path):
    built = build_bop(tmp_path / "d", SMALL)
    (built.split_dir / "notes").mkdir()
    with pytest.raises(DatasetError, match=r"notes: expected only scene folders"):
        open_bop(built.root, "test")
