"""A tiny T-LESS-layout dataset generated and loaded back, with the invariants docs/datasets.md lists."""

import dataclasses
import json

import numpy as np
import pytest

from bop_cender.data.bop_io import load_depth, load_mask
from bop_cender.data.tless import open_tless
from bop_cender.errors import ConfigError
from bop_cender.geometry.poses import invert_pose, pose_from_bop
from bop_cender.synth.demo import DEMO_VERSION
from bop_cender.synth.generate import generate
from bop_cender.synth.record import RECORD_FILE
from bop_cender.synth.write_tless import TLESS_CATALOGUE_SEED, TlessSpec

SPEC = TlessSpec(n_scenes=1, n_views=4, pbr_scenes=1, pbr_images=2, width=160, height=120, seed=3)


@pytest.fixture(scope="module")
def tless_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("tless")
    report = generate("tless", root, SPEC, workers=1, progress=False)
    assert report.written == 2 and report.targets > 0
    return root


def load(path):
    return json.loads(path.read_text())


def test_full_bop_file_set(tless_root):
    for p in (
        "camera_primesense.json",
        "test_targets_bop19.json",
        "models_cad/models_info.json",
        "models_eval/models_info.json",
    ):
        assert (tless_root / p).is_file(), p
    scene = tless_root / "test_primesense" / "000001"
    assert sorted(p.name for p in scene.iterdir()) == [
        "depth",
        "mask",
        "mask_visib",
        "rgb",
        "scene_camera.json",
        "scene_gt.json",
        "scene_gt_info.json",
    ]
    assert sorted(p.suffix for p in (scene / "rgb").iterdir()) == [".png"] * 4
    assert sorted(p.suffix for p in (tless_root / "train_pbr" / "000000" / "rgb").iterdir()) == [".jpg"] * 2
    cam = load(scene / "scene_camera.json")
    assert set(cam["0"]) == {"cam_K", "cam_R_w2c", "cam_t_w2c", "depth_scale", "elev", "mode"}
    assert len({tuple(c["cam_K"]) for c in cam.values()}) > 1  # per-image K


def test_gt_info_consistent_with_masks_and_depth(tless_root):
    scene = tless_root / "test_primesense" / "000001"
    cam, gt, info = (load(scene / f) for f in ("scene_camera.json", "scene_gt.json", "scene_gt_info.json"))
    for im in gt:
        depth = load_depth(scene / "depth" / f"{int(im):06d}.png", cam[im]["depth_scale"])
        assert len(info[im]) == len(gt[im])
        for gt_id, entry in enumerate(info[im]):
            mask = load_mask(scene / "mask" / f"{int(im):06d}_{gt_id:06d}.png")
            visib = load_mask(scene / "mask_visib" / f"{int(im):06d}_{gt_id:06d}.png")
            assert visib.sum() == entry["px_count_visib"]
            assert (visib <= mask).all()
            assert entry["px_count_all"] >= mask.sum()  # counted on the 3x canvas
            assert entry["visib_fract"] == pytest.approx(entry["px_count_visib"] / entry["px_count_all"])
            if visib.any():
                ys, xs = np.nonzero(visib)
                assert entry["bbox_visib"] == [xs.min(), ys.min(), xs.max() - xs.min() + 1, ys.max() - ys.min() + 1]
                assert (depth[visib] > 0).all()
        # Objects are static in the world: the same world pose from every image.
        if im != "0":
            for a, b in zip(gt["0"], gt[im], strict=True):
                Wa = invert_pose(pose_from_bop(cam["0"]["cam_R_w2c"], cam["0"]["cam_t_w2c"])) @ pose_from_bop(
                    a["cam_R_m2c"], a["cam_t_m2c"]
                )
                Wb = invert_pose(pose_from_bop(cam[im]["cam_R_w2c"], cam[im]["cam_t_w2c"])) @ pose_from_bop(
                    b["cam_R_m2c"], b["cam_t_m2c"]
                )
                np.testing.assert_allclose(Wa, Wb, atol=1e-6)


def test_depth_matches_gt_pose(tless_root):
    """The depth PNG at the projection of an object's centre is close to its camera z."""
    scene = tless_root / "test_primesense" / "000001"
    cam, gt, info = (load(scene / f) for f in ("scene_camera.json", "scene_gt.json", "scene_gt_info.json"))
    depth = load_depth(scene / "depth" / "000000.png", 0.1)
    assert depth.dtype == np.float32 and depth.shape == (120, 160)
    assert 500 < np.median(depth[depth > 0]) < 1100


def test_targets_follow_the_visib_fract_rule(tless_root):
    targets = load(tless_root / "test_targets_bop19.json")
    gt = load(tless_root / "test_primesense" / "000001" / "scene_gt.json")
    info = load(tless_root / "test_primesense" / "000001" / "scene_gt_info.json")
    expected = {}
    for im in gt:
        for g, i in zip(gt[im], info[im], strict=True):
            if i["visib_fract"] >= 0.1:
                key = (1, int(im), g["obj_id"])
                expected[key] = expected.get(key, 0) + 1
    assert {(t["scene_id"], t["im_id"], t["obj_id"]): t["inst_count"] for t in targets} == expected


def test_loaded_by_our_loader(tless_root):
    ds = open_tless(tless_root, "test", n_views=2)
    scenes = list(ds.scenes())
    assert len(scenes) == 2 and sorted(im for s in scenes for im in s.im_ids) == [0, 1, 2, 3]
    assert ds.has_depth and ds.residuals["gt_max_mm"] < 1e-6
    pbr = open_tless(tless_root, "train_pbr")
    assert len(pbr) == 2 and all(len(s.views) == 1 for s in pbr.scenes())


def test_camera_file_matches_the_images_intrinsics_at_any_size(tless_root):
    cam = load(tless_root / "camera_primesense.json")
    K = load(tless_root / "test_primesense" / "000001" / "scene_camera.json")["0"]["cam_K"]
    assert (cam["width"], cam["height"]) == (SPEC.width, SPEC.height)
    assert cam["fx"] == pytest.approx(K[0]) and cam["fy"] == pytest.approx(K[4])


MODEL_FILES = ("models_cad", "models_eval")


def model_bytes(root) -> dict[str, bytes]:
    """Every file of the model folders, by path: byte-identical models mean the same catalogue."""
    return {
        p.relative_to(root).as_posix(): p.read_bytes()
        for folder in MODEL_FILES
        for p in sorted((root / folder).rglob("*"))
        if p.is_file()
    }


def models_only(spec: TlessSpec, **changes) -> TlessSpec:
    """``spec`` with no scenes: what is written is the models, the camera file and the record (fast)."""
    return dataclasses.replace(spec, n_scenes=0, pbr_scenes=0, **changes)


def test_the_catalogue_is_the_same_for_every_seed(tless_root, tmp_path):
    """Sets of two seeds share their 30 models byte for byte (a network trained on one is tested on the other)."""
    other = tmp_path / "seed4"
    generate("tless", other, models_only(SPEC, seed=4), progress=False)
    ours = model_bytes(tless_root)
    assert model_bytes(other) == ours
    assert sorted(int(k) for k in load(tless_root / "models_cad" / "models_info.json")) == list(range(1, 31))
    assert len([k for k in ours if k.endswith(".ply")]) == 2 * 30
    another = tmp_path / "catalogue5"
    generate("tless", another, models_only(SPEC, catalogue_seed=5), progress=False)
    theirs = model_bytes(another)
    assert theirs.keys() == ours.keys() and all(theirs[k] != ours[k] for k in ours)


def test_piles_show_a_few_objects_of_the_catalogue(tless_root):
    for split in ("test_primesense", "train_pbr"):
        for scene in (tless_root / split).iterdir():
            gt = load(scene / "scene_gt.json")
            shown = {o["obj_id"] for o in gt["0"]}
            assert shown <= set(range(1, 31)) and 1 <= len(shown) <= SPEC.models_per_scene[1]
            assert len(shown) < len(gt["0"]) <= SPEC.objects_per_scene[1]  # some several times


def test_the_record_names_the_seeds_and_a_mismatched_resume_is_refused(tless_root, tmp_path):
    record = load(tless_root / RECORD_FILE)
    assert record == {
        "generator": "bop-cender synth",
        "generator_version": DEMO_VERSION,
        "layout": "tless",
        "seed": 3,
        "catalogue_seed": TLESS_CATALOGUE_SEED,
        "complete": True,
    }
    root = tmp_path / "ds"
    generate("tless", root, models_only(SPEC), progress=False)
    before = sorted(p.relative_to(root) for p in root.rglob("*"))
    for changes, field in (({"seed": 4}, "seed"), ({"catalogue_seed": 5}, "catalogue_seed")):
        with pytest.raises(ConfigError) as err:
            generate("tless", root, models_only(SPEC, **changes), progress=False)
        assert err.value.field == field and err.value.file == str(root / RECORD_FILE)
        assert f"{RECORD_FILE}: {field}: this dataset was generated with {field}" in str(err.value)
    from bop_cender.synth.write_dimo import DimoSpec

    with pytest.raises(ConfigError, match="layout"):
        generate("dimo", root, DimoSpec(n_scenes=0, seed=3), progress=False)
    assert sorted(p.relative_to(root) for p in root.rglob("*")) == before  # refused before writing anything
    generate("tless", root, models_only(SPEC), progress=False)  # the same seeds resume


def test_randomised_appearance_changes_train_pbr_images_only(tless_root, tmp_path):
    """``--appearance randomised``: train_pbr looks other, its piles, poses, masks and depth do not; test is untouched."""
    import hashlib

    from bop_cender.data.bop_io import load_rgb

    def files(folder):
        return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest() for p in folder.rglob("*")
                if p.is_file()}  # fmt: skip

    randomised = tmp_path / "randomised"
    generate("tless", randomised, dataclasses.replace(SPEC, appearance="randomised"), progress=False)
    assert load(randomised / RECORD_FILE)["appearance"] == "randomised"
    assert "appearance" not in load(tless_root / RECORD_FILE)
    assert files(randomised / "test_primesense") == files(tless_root / "test_primesense")
    ours, theirs = files(tless_root / "train_pbr"), files(randomised / "train_pbr")
    assert ours.keys() == theirs.keys()
    for name in ours:
        if "/rgb/" in name:
            a = load_rgb(tless_root / "train_pbr" / name).astype(float)
            assert np.abs(a - load_rgb(randomised / "train_pbr" / name)).mean() > 5, name
        else:  # GT files, masks, depth: the same pile at the same poses (the table is in depth either way)
            assert ours[name] == theirs[name], name
    with pytest.raises(ConfigError, match="appearance 'randomised', not 'default'"):
        generate("tless", randomised, SPEC, progress=False)
    with pytest.raises(ValueError, match="appearance must be one of"):
        TlessSpec(appearance="pbr")


def test_spec_is_validated():
    with pytest.raises(ValueError, match="models_per_scene"):
        TlessSpec(models_per_scene=(3, 31))
    with pytest.raises(ValueError, match="objects_per_scene"):
        TlessSpec(objects_per_scene=(5, 2))
    with pytest.raises(ValueError, match="seeds"):
        TlessSpec(catalogue_seed=-1)


def test_visible_pixels_outside_the_objects_own_render_do_not_count():
    """The scene render and the object's own render can differ by a pixel along a shared edge: visib_fract
    stays <= 1 (the loaders refuse more, as they would for a real dataset)."""
    import trimesh

    from bop_cender.render.mesh import prepare_mesh
    from bop_cender.synth.gt_info import object_visibility

    mesh = prepare_mesh(trimesh.creation.box(extents=(20.0, 20.0, 20.0)))
    T = np.eye(4)
    T[2, 3] = 200.0
    K = np.array([[200.0, 0, 32], [0, 200.0, 32], [0, 0, 1]])
    alone = object_visibility([mesh], T[None], K, np.full((64, 64), -1), np.ones((64, 64)), [0])[0]
    instance = np.where(alone.mask, 0, -1)
    instance[0, 0] = 0  # a pixel the object's own render does not cover
    info = object_visibility([mesh], T[None], K, instance, np.ones((64, 64)), [0])[0].info
    assert info["visib_fract"] == 1.0 and info["px_count_visib"] == info["px_count_all"]
