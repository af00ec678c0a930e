"""A tiny DIMO-layout dataset generated and loaded back, with the invariants docs/datasets.md lists ("DIMO")."""

import hashlib
import json
import shutil

import numpy as np
import pytest

from bop_cender.data.dimo import CARRIER_MIN_ID, DimoSelection, open_dimo
from bop_cender.geometry.poses import invert_pose, pose_from_bop
from bop_cender.synth.demo import DEMO_VERSION
from bop_cender.synth.generate import generate
from bop_cender.synth.record import RECORD_FILE
from bop_cender.synth.write_dimo import DIMO_CATALOGUE_SEED, DimoSpec

# Small images keep this fast; the layout does not depend on the size (the demo uses DIMO small, 320x256).
SPEC = DimoSpec(
    n_scenes=2, n_viewpoints=3, variants=(0, 3, 17), carriers=(2, 1), compositions=(1, 3), width=160, height=128, seed=5
)


@pytest.fixture(scope="module")
def dimo_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("dimo")
    report = generate("dimo", root, SPEC, workers=1, progress=False)
    assert report.written == 2 * 4 and report.skipped == 0  # 2 scenes x (real + 3 variants)
    return root


def digest(folder):
    h = hashlib.sha256()
    for p in sorted(folder.rglob("*")):
        if p.is_file():
            h.update(p.relative_to(folder).as_posix().encode())
            h.update(p.read_bytes())
    return h.hexdigest()


def load(path):
    return json.loads(path.read_text())


def test_only_the_files_real_dimo_has(dimo_root):
    assert (dimo_root / "models" / "models_info.json").is_file()
    assert (dimo_root / "models" / "construction").is_dir()
    folders = sorted(p.name for p in (dimo_root / "sim_jaigo").iterdir())
    assert folders == ["000000_00", "000000_03", "000000_17", "000001_00", "000001_03", "000001_17"]
    assert sorted(p.name for p in (dimo_root / "real_jaigo").iterdir()) == ["000000", "000001"]
    for scene in (dimo_root / "real_jaigo" / "000000", dimo_root / "sim_jaigo" / "000000_17"):
        names = sorted(p.name for p in scene.iterdir())
        assert names == ["rgb", "scene_camera.json", "scene_gt.json", "scene_gt_world.json", "scene_info.json"]
        assert sorted(p.name for p in (scene / "rgb").iterdir()) == [f"{i:06d}.png" for i in range(3)]
    assert not list(dimo_root.rglob("mask*")) and not list(dimo_root.rglob("scene_gt_info.json"))
    assert len(list((dimo_root / "contact_sheets").glob("*.png"))) == 8
    # Beside the real layout only our record (which the loaders do not read: see the loader test below).
    assert sorted(p.name for p in dimo_root.iterdir() if p.is_file()) == [RECORD_FILE]
    assert load(dimo_root / RECORD_FILE) == {
        "generator": "bop-cender synth",
        "generator_version": DEMO_VERSION,
        "layout": "dimo",
        "seed": 5,
        "catalogue_seed": DIMO_CATALOGUE_SEED,
        "complete": True,
    }


def test_the_writers_invariants(dimo_root):
    rigs = {}
    for scene in sorted((dimo_root / "real_jaigo").iterdir()) + sorted((dimo_root / "sim_jaigo").iterdir()):
        cam, gt, world, info = (
            load(scene / f) for f in ("scene_camera.json", "scene_gt.json", "scene_gt_world.json", "scene_info.json")
        )
        # 1. identical image-id key sets (strings)
        assert set(cam) == set(gt) == set(info) == {"0", "1", "2"}
        for im, entry in cam.items():
            # 2. same length, order, int obj_id as scene_gt_world
            assert [o["obj_id"] for o in gt[im]] == [o["obj_id"] for o in world]
            assert all(type(o["obj_id"]) is int for o in gt[im])
            # 3. T_m2c == inv(T_c2w) @ T_m2w; c2w and w2c consistent
            T_c2w = pose_from_bop(entry["cam_R_c2w"], entry["cam_t_c2w"])
            T_w2c = pose_from_bop(entry["cam_R_w2c"], entry["cam_t_w2c"])
            np.testing.assert_allclose(T_w2c, invert_pose(T_c2w), atol=1e-9)
            for o, ow in zip(gt[im], world, strict=True):
                T_m2c = pose_from_bop(o["cam_R_m2c"], o["cam_t_m2c"])
                T_m2w = pose_from_bop(ow["cam_R_m2w"], ow["cam_t_m2w"])
                np.testing.assert_allclose(T_m2c, invert_pose(T_c2w) @ T_m2w, atol=1e-6)
            # 4. viewpoint k has the same camera pose in every scene
            vp = info[im]["viewpoint"]
            assert vp == int(im)
            rigs.setdefault(vp, T_c2w)
            np.testing.assert_allclose(rigs[vp], T_c2w, atol=1e-9)
            assert set(info[im]) == {"light", "carrier", "parts", "viewpoint"}
        assert any(o["obj_id"] >= CARRIER_MIN_ID for o in world)  # the carrier is in the GT, as an occluder


def test_variants_share_or_change_poses(dimo_root):
    real = load(dimo_root / "real_jaigo" / "000000" / "scene_gt_world.json")
    assert load(dimo_root / "sim_jaigo" / "000000_00" / "scene_gt_world.json") == real  # twin
    assert load(dimo_root / "sim_jaigo" / "000000_03" / "scene_gt_world.json") == real  # random light, real poses
    assert load(dimo_root / "sim_jaigo" / "000000_17" / "scene_gt_world.json") != real  # random poses
    real_info = load(dimo_root / "real_jaigo" / "000000" / "scene_info.json")["0"]
    assert load(dimo_root / "sim_jaigo" / "000000_00" / "scene_info.json")["0"]["light"] == real_info["light"]
    assert load(dimo_root / "sim_jaigo" / "000000_03" / "scene_info.json")["0"]["light"] == 103


def test_sim_to_real_gap_in_appearance(dimo_root):
    from bop_cender.data.bop_io import load_rgb

    real = load_rgb(dimo_root / "real_jaigo" / "000000" / "rgb" / "000000.png").astype(float)
    sim = load_rgb(dimo_root / "sim_jaigo" / "000000_00" / "rgb" / "000000.png").astype(float)
    assert real.shape == sim.shape == (128, 160, 3)
    assert np.abs(real - sim).mean() > 5  # same poses, different light / material / noise model
    # Not flat-shaded toys: noise and texture everywhere (high-frequency energy in both).
    for img in (real, sim):
        assert np.abs(np.diff(img, axis=1)).mean() > 2


def test_loaded_by_our_loader_with_the_paper_selection(dimo_root):
    for split in ("real", "sim", "train"):
        ds = open_dimo(dimo_root, split)
        # Scene 0 (carrier 2, composition 1) is kept, scene 1 (carrier 1, mixed) is dropped.
        assert [s.scene_id for s in ds.scenes()] == {"real": ["000000"], "sim": ["000000_00"], "train": ["000000_17"]}[
            split
        ]
        scene = ds.scene(ds.scene_keys[0])
        assert [v.im_id for v in scene.views] == [0, 2]  # viewpoints 0, 2 of the 3 written
        assert ds.residuals["gt_max_mm"] < 1e-6
    everything = open_dimo(dimo_root, "sim", DimoSelection.everything())
    assert len(everything) == 6


def test_deterministic_and_resumable(dimo_root, tmp_path):
    spec = DimoSpec(n_scenes=1, n_viewpoints=2, variants=(0,), width=96, height=80, seed=5, contact_sheets=False)
    a, b = tmp_path / "a", tmp_path / "b"
    generate("dimo", a, spec, progress=False)
    generate("dimo", b, spec, progress=False)
    assert digest(a) == digest(b)
    shutil.rmtree(a / "sim_jaigo" / "000000_00")
    report = generate("dimo", a, spec, progress=False)
    assert (report.written, report.skipped) == (1, 1)
    assert digest(a) == digest(b)
    assert not list(a.rglob(".*.partial*"))


def test_the_catalogue_is_the_same_for_every_seed(dimo_root, tmp_path):
    """DIMO has one catalogue (6 parts, 3 carriers): sets of two seeds share their models byte for byte."""
    other = tmp_path / "seed6"
    generate("dimo", other, DimoSpec(n_scenes=0, seed=6), progress=False)
    for folder in ("models", "models_eval"):
        assert digest(other / folder) == digest(dimo_root / folder)
    assert sorted(int(k) for k in load(dimo_root / "models" / "models_info.json")) == [1, 2, 3, 4, 5, 6, 100, 101, 102]
    another = tmp_path / "catalogue7"
    generate("dimo", another, DimoSpec(n_scenes=0, seed=5, catalogue_seed=7), progress=False)
    assert digest(another / "models") != digest(dimo_root / "models")
    assert load(another / RECORD_FILE)["catalogue_seed"] == 7


def test_randomised_appearance_changes_the_look_not_the_ground_truth(dimo_root, tmp_path):
    """``--appearance randomised``: the same scenes (poses, cameras, GT), other images; recorded, resumable."""
    from dataclasses import replace

    from bop_cender.data.bop_io import load_rgb

    spec = DimoSpec(n_scenes=1, n_viewpoints=2, variants=(0, 17), width=96, height=80, seed=5, contact_sheets=False)
    plain, randomised = tmp_path / "plain", tmp_path / "randomised"
    generate("dimo", plain, spec, progress=False)
    generate("dimo", randomised, replace(spec, appearance="randomised"), progress=False)
    assert RECORD_FILE in {p.name for p in plain.iterdir()}
    assert "appearance" not in load(plain / RECORD_FILE)  # the default's record keeps its bytes
    assert load(randomised / RECORD_FILE)["appearance"] == "randomised"
    for folder in ("real_jaigo/000000", "sim_jaigo/000000_00", "sim_jaigo/000000_17"):
        for name in ("scene_gt.json", "scene_camera.json", "scene_gt_world.json", "scene_info.json"):
            assert load(plain / folder / name) == load(randomised / folder / name), (folder, name)
    # real_jaigo keeps the real camera's look; the sim folders get another one.
    assert digest(plain / "real_jaigo") == digest(randomised / "real_jaigo")
    a = load_rgb(plain / "sim_jaigo" / "000000_17" / "rgb" / "000000.png").astype(float)
    b = load_rgb(randomised / "sim_jaigo" / "000000_17" / "rgb" / "000000.png").astype(float)
    assert np.abs(a - b).mean() > 5
    # A resume with the other appearance would mix two looks in one set: refused, naming the field.
    from bop_cender.errors import ConfigError

    with pytest.raises(ConfigError, match="appearance 'randomised', not 'default'"):
        generate("dimo", randomised, spec, progress=False)
    with pytest.raises(ValueError, match="appearance must be one of"):
        DimoSpec(appearance="pbr")


def test_randomised_styles_span_more_than_the_sim_and_real_cameras():
    """Across many draws the randomised domain covers both cameras' ranges and goes past them."""
    from bop_cender.synth.styles import make_style

    centre = np.zeros(3)
    rng = np.random.default_rng(0)
    styles = [make_style(rng, "randomised", 4, centre, carrier_index=0) for _ in range(300)]
    metals = [m for s in styles for m in s.materials[1:]]
    rough = np.array([m.roughness for m in metals])
    grey = np.array([np.mean(m.base_color) for m in metals])
    assert rough.min() < 0.05 and rough.max() > 0.6  # sim 0.1-0.45, real 0.05-0.3
    assert grey.min() < 0.4 and grey.max() > 0.9  # sim and real 0.55-0.9
    assert {s.env_style for s in styles} == {"studio", "hall"}
    assert {s.background for s in styles} == {"texture", "flat"}
    carriers = [s.materials[0] for s in styles]
    assert any(c.texture for c in carriers) and any(not c.texture for c in carriers)  # textured and plain
    assert {len(s.lights) for s in styles} == {1, 2, 3, 4}
    exposure = np.array([s.exposure for s in styles])
    assert exposure.min() < 0.6 and exposure.max() > 1.5
    # Deterministic by seed; the other domains' draws are not touched by the new one.
    again = make_style(np.random.default_rng(0), "randomised", 4, centre, carrier_index=0)
    assert again == styles[0]
    fixed = make_style(np.random.default_rng(1), "randomised", 4, centre, light_id=3, carrier_index=0)
    assert fixed.lights == make_style(np.random.default_rng(2), "sim", 4, centre, light_id=3, carrier_index=0).lights


def test_randomised_plastic_styles_hide_the_table_from_about_half_the_piles():
    """T-LESS's randomised look: plastic of any colour and finish; the carrier shaded as background now and then."""
    from bop_cender.synth.styles import make_style

    rng = np.random.default_rng(0)
    styles = [make_style(rng, "randomised", 4, np.zeros(3), carrier_index=0, surface="plastic") for _ in range(300)]
    plastics = [m for s in styles for m in s.materials[1:]]
    assert max(m.metallic for m in plastics) <= 0.3 and np.mean([m.metallic == 0 for m in plastics]) > 0.7
    colour = np.array([np.ptp(m.base_color) for m in plastics])
    assert (colour < 0.1).mean() > 0.3 and (colour > 0.3).mean() > 0.2  # greys and colours
    hidden = np.array([s.hidden == (0,) for s in styles])
    assert 0.4 < hidden.mean() < 0.6 and all(s.hidden in ((), (0,)) for s in styles)
    assert all(make_style(rng, "randomised", 4, np.zeros(3), carrier_index=0).hidden == () for _ in range(50))
    with pytest.raises(ValueError, match="unknown surface"):
        make_style(rng, "randomised", 4, np.zeros(3), carrier_index=0, surface="wood")


def test_a_hidden_instance_is_shaded_as_background_but_kept_in_depth_and_instances():
    """``Style.hidden``: the table is in the depth and instance maps (it occludes, GT masks see it), not the RGB."""
    from dataclasses import replace

    from bop_cender.render.mesh import prepare_mesh
    from bop_cender.render.shading import SensorModel
    from bop_cender.synth.imaging import render_views
    from bop_cender.synth.parts import make_carrier
    from bop_cender.synth.styles import make_style

    carrier = make_carrier(np.random.default_rng(1), (300.0, 200.0, 20.0))
    T_wm = np.eye(4)[None]
    K = np.array([[150.0, 0, 48], [0, 150.0, 40], [0, 0, 1]])
    T_cw = np.diag([1.0, -1.0, -1.0, 1.0])
    T_cw[2, 3] = 600.0  # looking down at the carrier from 600 mm
    style = make_style(np.random.default_rng(2), "randomised", 1, np.zeros(3), carrier_index=0, surface="plastic")
    style = replace(style, sensor=SensorModel(read_noise=0.0, shot_noise=0.0), background="flat")
    mesh = [prepare_mesh(carrier.mesh)]
    shown = render_views(mesh, T_wm, [(K, T_cw)], 80, 96, replace(style, hidden=()), np.random.default_rng(3))[0]
    hidden = render_views(mesh, T_wm, [(K, T_cw)], 80, 96, replace(style, hidden=(0,)), np.random.default_rng(3))[0]
    on_carrier = shown.instance == 0
    assert on_carrier.mean() > 0.3 and (hidden.instance == shown.instance).all()
    np.testing.assert_array_equal(hidden.depth, shown.depth)
    assert np.abs(hidden.rgb.astype(float) - shown.rgb).mean() > 5  # the carrier's pixels are other
    flat = hidden.rgb.reshape(-1, 3)
    assert np.ptp(flat, axis=0).max() <= 1  # all background: one flat colour


@pytest.mark.parametrize("flag, value", [("--variants", "99"), ("--carriers", "7"), ("--compositions", "99")])
def test_synth_names_the_flag_of_a_value_out_of_range(tmp_path, capsys, flag, value) -> None:
    from bop_cender.cli import main

    out = tmp_path / "d"
    assert main(["synth", "--layout", "dimo", "--out", str(out), "--scenes", "1", flag, value]) == 2
    err = capsys.readouterr().err
    assert f"({flag}) must be" in err and f"{value}" in err and "Traceback" not in err and not out.exists()
