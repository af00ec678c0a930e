"""The T-LESS loader on the hand-written fixture ``tests/fixtures/tless_hand``.

The fixture's numbers were typed by hand (the layout of docs/datasets.md): scene 1 has images 0, 1, 2 and 42
(42 is a T-LESS test entry as third-party code quotes it, verbatim), three static objects (world poses below), and
``cam_R_m2c``/``cam_t_m2c`` derived by hand as ``T_cam_world @ T_world_model``; image 42's are
rounded as T-LESS rounds them (R to 6 digits, t to 0.01 mm). Image 1 lists the objects in another
order. Targets: images 0, 1 and 42 (not 2).
"""

import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from bop_cender.data.registry import DatasetRequest, open_dataset
from bop_cender.data.tless import SPLITS, open_tless
from bop_cender.errors import ConfigError, DatasetWarning
from bop_cender.geometry.poses import make_pose, pose_from_bop

try:
    from tests.data.bop_builder import BopSpec, build_bop
except ImportError:  # pytest's default import mode puts tests/data itself on sys.path
    from bop_builder import BopSpec, build_bop

HAND = Path(__file__).resolve().parents[1] / "fixtures" / "tless_hand"

RZ90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
#: The hand-made world: (obj_id, T_world_model, gt_ids per image, visib_fract per image).
WORLD = {
    "A": (1, make_pose(np.eye(3), [0, 0, 30]), {0: 0, 1: 1, 2: 0, 42: 0}, {0: 1.0, 1: 1.0, 2: 0.05, 42: 0.8}),
    "B": (5, make_pose(RZ90, [50, 0, 20]), {0: 1, 1: 2, 2: 1, 42: 1}, {0: 0.75, 1: 0.25, 2: 0.6, 42: 0.0}),
    "C": (1, make_pose(np.eye(3), [-40, 30, 30]), {0: 2, 1: 0, 2: 2, 42: 2}, {0: 0.5, 1: 0.0, 2: 1.0, 42: 0.4}),
}
QUOTED_42 = {
    "K": [1075.65091572, 0.0, 367.06888344, 0.0, 1073.90347929, 247.72159802, 0.0, 0.0, 1.0],
    "R": [-0.529601, 0.848203, 0.00860459, 0.810945, 0.50926, -0.288136, -0.24878, -0.145619, -0.957551],
    "t": [-5.19015, 23.2188, 789.59],
}


def _strict(fn, *args, **kwargs):
    """Call with DatasetWarning turned into an error: the hand fixture must load cleanly."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", DatasetWarning)
        return fn(*args, **kwargs)


def _by_world_position(gt):
    return {(g.obj_id, tuple(np.round(g.T_world_model[:3, 3], 2))): g for g in gt}


def test_hand_fixture_dataset():
    ds = _strict(open_tless, HAND, "test")
    assert ds.name == "tless" and ds.split == "test"
    assert ds.scene_keys == ["000001/g00"]  # 3 target images, n_views 5: one group
    assert ds.image_size == (16, 12) and ds.has_depth
    assert sorted(ds.models) == [1, 5] and ds.models[1].path.parent.name == "models_cad"
    assert ds.eval_models[5].path.parent.name == "models_eval"
    assert ds.models[1].symmetries_continuous[0].axis == (0.0, 0.0, 1.0)
    assert ds.models[5].symmetries_discrete == [[-1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]]
    assert ds.models[1].diameter == 33.166248
    np.testing.assert_array_equal(ds.models[5].center, [0, 0, 0])
    assert len(ds.models[5].mesh.vertices) == 4
    assert "3 images, 5 targets in 1 scenes" in " ".join(ds.selection)


def test_hand_fixture_views():
    scene = _strict(open_tless, HAND, "test").scene("000001/g00")
    assert scene.im_ids == [0, 1, 42] and scene.key == "000001/g00"
    v0, v1, v42 = scene.views
    np.testing.assert_array_equal(v0.K, [[20, 0, 8], [0, 20, 6], [0, 0, 1]])
    np.testing.assert_array_equal(v1.K, [[20.5, 0, 7.5], [0, 20.5, 6.5], [0, 0, 1]])
    np.testing.assert_array_equal(v42.K.ravel(), QUOTED_42["K"])
    np.testing.assert_array_equal(v0.T_cam_world, make_pose(np.diag([1.0, -1.0, -1.0]), [0, 0, 700]))
    np.testing.assert_array_equal(v1.T_cam_world, make_pose([[0, 1, 0], [1, 0, 0], [0, 0, -1]], [10, -20, 650]))
    np.testing.assert_array_equal(v42.T_cam_world, pose_from_bop(QUOTED_42["R"], QUOTED_42["t"]))
    assert v42.depth_scale == 0.1 and dict(v42.info) == {"elev": 75, "mode": 0}
    assert (v42.width, v42.height) == (16, 12)
    assert v1.rgb_path == HAND / "test_primesense/000001/rgb/000001.png"
    assert v1.depth_path == HAND / "test_primesense/000001/depth/000001.png"
    assert [p.name for p in v42.mask_paths] == ["000042_000000.png", "000042_000001.png", "000042_000002.png"]
    assert v42.mask_visib_paths[2].parent.name == "mask_visib"


def test_hand_fixture_world_poses_and_association():
    ds = _strict(open_tless, HAND, "test")
    gt = _by_world_position(ds.scene("000001/g00").gt)
    assert len(gt) == 3
    for obj_id, T, gt_ids, visib in WORLD.values():
        g = gt[(obj_id, tuple(T[:3, 3]))]
        np.testing.assert_array_equal(g.T_world_model, T)  # from image 0, exact
        assert dict(g.gt_ids) == {im: gt_ids[im] for im in (0, 1, 42)}
        assert dict(g.visib_fract) == {im: visib[im] for im in (0, 1, 42)}
    # image 42 is rounded: a residual of a few micrometres, well below the 0.1 mm warning
    assert 0.001 < ds.residuals["gt_max_mm"] < 0.01
    assert ds.residuals["gt_max_rad"] < 1e-5 and ds.residuals["gt_pairs"] == 6


def test_hand_fixture_without_targets_uses_every_image(tmp_path):
    root = tmp_path / "tless"
    shutil.copytree(HAND, root)
    (root / "test_targets_bop19.json").unlink()
    ds = _strict(open_tless, root, "test", n_views=2, seed=3)
    scenes = list(ds.scenes())
    assert sorted(im for s in scenes for im in s.im_ids) == [0, 1, 2, 42]
    assert [len(s.im_ids) for s in scenes] == [2, 2]
    for scene in scenes:
        gt = _by_world_position(scene.gt)
        for obj_id, T, gt_ids, _ in WORLD.values():
            g = gt[(obj_id, tuple(T[:3, 3]))]
            np.testing.assert_allclose(g.T_world_model, T, atol=0.01)
            assert dict(g.gt_ids) == {im: gt_ids[im] for im in scene.im_ids}


def test_registry_and_split_names():
    ds = open_dataset(DatasetRequest("tless", HAND, "test"))
    assert ds.name == "tless" and ds.scene_keys == ["000001/g00"]
    assert open_dataset(DatasetRequest("tless", HAND)).split == "test"
    assert open_tless(HAND, "test_primesense").scene_keys == ds.scene_keys


def test_unknown_split_or_model_type():
    with pytest.raises(ConfigError, match=r"unknown T-LESS split 'val'; expected one of test, train_pbr, train"):
        open_tless(HAND, "val")
    with pytest.raises(ConfigError, match="split folder train_primesense/ not found"):
        open_tless(HAND, "train")
    with pytest.raises(ConfigError, match="unknown T-LESS model type 'mesh'"):
        open_tless(HAND, "test", model_type="mesh")
    with pytest.raises(
        ConfigError, match=r"models_reconst/ not found; models folders: \['models_cad', 'models_eval'\]"
    ):
        open_tless(HAND, "test", model_type="reconst")
    assert open_tless(HAND, "test", model_type="eval").models[1].path.parent.name == "models_eval"


def test_split_table_is_data():
    assert SPLITS["test"].folder == "test_primesense" and SPLITS["test"].image_size == (720, 540)
    assert SPLITS["train_pbr"].image_size == (720, 540) and SPLITS["train"].folder == "train_primesense"


def test_built_tless_layout_pbr_and_test(tmp_path):
    built = build_bop(
        tmp_path / "tless",
        BopSpec(n_scenes=1, n_images=4, pbr_scenes=1, pbr_images=2),
        models_dirs=("models_cad", "models_eval"),
    )
    pbr = _strict(open_tless, built.root, "train_pbr")
    assert pbr.scene_keys == ["000000/i000000", "000000/i000001"]
    assert pbr.scene(pbr.scene_keys[0]).views[0].rgb_path.suffix == ".jpg"
    test = _strict(open_tless, built.root, "test", n_views=2)
    assert sorted(im for s in test.scenes() for im in s.im_ids) == built.target_images["000001"]


def test_table_size_is_used_without_a_camera_file(tmp_path):
    built = build_bop(tmp_path / "tless", BopSpec(n_scenes=1, n_images=2, pbr_scenes=0), models_dirs=("models_cad",))
    (built.root / "camera_primesense.json").unlink()
    with pytest.warns(DatasetWarning, match=r"test_primesense constant says 720x540 but .* is 32x24"):
        ds = open_tless(built.root, "test")
    assert ds.image_size == (32, 24)
