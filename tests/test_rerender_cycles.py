"""``scripts/rerender_cycles.py``: a copy whose images Blender's Cycles path traced, the GT objects exactly where
the dataset's masks and our renderer put them, the same bytes for the same seed, resumable per scene; refusals
before anything is written.

The renders need ``bpy`` (``pip install bpy==4.2.0``, Python 3.11; not in the test extras, so CI skips them);
the refusals, the camera conversion, the support plane and the draws run everywhere (a stand-in ``bpy`` module
where the script only needs the import to succeed).
"""

from __future__ import annotations

import filecmp
import importlib.util
import json
import sys
import types
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

sys.path.insert(0, str(Path(__file__).parent))
sys.path.insert(0, str(Path(__file__).parents[1] / "scripts"))
import cycles_look  # noqa: E402
import method_data  # noqa: E402
import rerender_cycles  # noqa: E402

from bop_cender.data.registry import DatasetRequest, open_dataset  # noqa: E402

HAS_BPY = importlib.util.find_spec("bpy") is not None
needs_bpy = pytest.mark.skipif(
    not HAS_BPY, reason="bpy (Blender as a Python module) is not installed: pip install bpy==4.2.0 (Python 3.11)"
)
#: Few samples and threads: the geometry does not depend on them, the test's CPU time does.
FAST = ["--samples", "2", "--threads", "2"]


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(1, (a | b).sum()))


def _our_instances(scene, view, dataset) -> np.ndarray:
    """``(H, W)`` our renderer's instance map of ``view`` (the scene_gt index, -1 on background)."""
    import torch

    from bop_cender.meshes import MeshCache
    from bop_cender.render.rasterizer import render_scene

    meshes = MeshCache(dataset.models)
    T = np.stack([view.T_cam_world @ g.T_world_model for g in scene.gt])[None]
    render = render_scene([meshes(g.obj_id) for g in scene.gt], torch.as_tensor(T, dtype=torch.float32),
                          torch.as_tensor(view.K, dtype=torch.float32)[None], int(view.height), int(view.width))  # fmt: skip
    return render.instance[0].numpy()


def _cycles_render(dataset, key: str, view, seed: int, samples: int, work: Path):
    """The script's render of ``view`` (its look, its Cycles seed): ``(rgb, index)``."""
    from cycles_scene import CyclesScene, denoiser_available

    renderer = CyclesScene(dataset.models, samples, 2, denoiser_available(), work)
    renderer.set_scene(dataset.scene(key), cycles_look.draw_look(rerender_cycles._rng(seed, key), dataset.name))
    return renderer.render(view, rerender_cycles._cycles_seed(seed, key, view.im_id))


def _images(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("rgb/*"))}


@needs_bpy
def test_a_dimo_layout_is_path_traced_where_the_gt_is_and_the_same_seed_gives_the_same_bytes(tmp_path: Path) -> None:
    src = method_data.build(tmp_path / "src", n_scenes=1)
    dst = tmp_path / "dst"
    assert rerender_cycles.main([str(src), str(dst), "--split", "real", "--seed", "3", *FAST]) == 0
    assert not (tmp_path / "dst.partial").exists()
    before = open_dataset(DatasetRequest("dimo", src, "real"))
    after = open_dataset(DatasetRequest("dimo", dst, "real"))
    assert after.scene_keys == before.scene_keys
    key = after.scene_keys[0]
    scene = after.scene(key)
    for view in scene.views:  # every image rendered again, same size and format
        ours = np.asarray(Image.open(src / Path(view.rgb_path).relative_to(dst))).astype(int)
        theirs = np.asarray(Image.open(view.rgb_path)).astype(int)
        assert theirs.shape == ours.shape and np.abs(theirs - ours).mean() > 5
    for json_file in src.rglob("*.json"):  # the GT as it was
        assert filecmp.cmp(json_file, dst / json_file.relative_to(src), shallow=False)
    # rendered again, apart from the run: the same bytes (deterministic), and the object index of the very image
    # written puts each GT object where our renderer draws it
    for view in scene.views[:2]:
        rgb, index = _cycles_render(after, key, view, 3, 2, tmp_path)
        np.testing.assert_array_equal(rgb, np.asarray(Image.open(view.rgb_path)))
        instances = _our_instances(scene, view, after)
        assert _iou(index > 0, instances >= 0) > 0.9
        for i in range(len(scene.gt)):
            if (instances == i).sum() >= 50:
                assert _iou(index == i + 1, instances == i) > 0.9, (view.im_id, i)


@needs_bpy
def test_a_tless_layout_matches_its_own_mask_files(tmp_path: Path) -> None:
    from bop_cender.synth.generate import generate
    from bop_cender.synth.write_tless import TlessSpec

    src = tmp_path / "src"
    generate("tless", src, TlessSpec(n_scenes=1, n_views=2, pbr_scenes=0, width=160, height=120, seed=5),
             progress=False)  # fmt: skip
    dst = tmp_path / "dst"
    assert rerender_cycles.main([str(src), str(dst), "--dataset", "tless", *FAST]) == 0
    dataset = open_dataset(DatasetRequest("tless", dst, "test", n_views=1))
    assert dataset.scene_keys == open_dataset(DatasetRequest("tless", src, "test", n_views=1)).scene_keys
    for key in dataset.scene_keys:
        (view,) = dataset.scene(key).views
        source = Image.open(src / Path(view.rgb_path).relative_to(dst))
        written = Image.open(view.rgb_path)
        assert (written.format, written.mode, written.size) == (source.format, source.mode, source.size)
        rgb, index = _cycles_render(dataset, key, view, 0, 2, tmp_path)
        np.testing.assert_array_equal(rgb, np.asarray(written))
        full = [np.asarray(Image.open(p)) > 0 for p in view.mask_paths]
        assert _iou(index > 0, np.any(full, axis=0)) > 0.9
        for i, g in enumerate(dataset.scene(key).gt):  # index: the loader's order; masks: the image's scene_gt order
            visible = np.asarray(Image.open(view.mask_visib_paths[g.gt_ids[view.im_id]])) > 0
            if visible.sum() >= 50:
                assert _iou(index == i + 1, visible) > 0.9, (key, i)


@needs_bpy
def test_unequal_focal_lengths_and_an_off_centre_principal_point(tmp_path: Path) -> None:
    """Blender's pixel aspect and lens shift: each object where our renderer draws it, through a camera whose
    fy is 1.3 fx and whose principal point is 14 and 30 pixels off the centre (the vertical shift is in units of
    the width's pixels: without the aspect in it, the objects are 7 pixels off). At one sample the index is our
    renderer's to the pixel; 0.95 leaves room for a pixel centre on an edge."""
    src = method_data.build(tmp_path / "src", n_scenes=1)
    for path in src.rglob("scene_camera.json"):
        cameras = json.loads(path.read_text())
        for entry in cameras.values():
            K = entry["cam_K"]
            K[4], K[2], K[5] = 1.3 * K[4], K[2] + 14.0, K[5] - 30.0
        path.write_text(json.dumps(cameras))
    dataset = open_dataset(DatasetRequest("dimo", src, "real"))
    key = dataset.scene_keys[0]
    scene = dataset.scene(key)
    view = scene.views[1]
    _, index = _cycles_render(dataset, key, view, 0, 1, tmp_path)
    instances = _our_instances(scene, view, dataset)
    for i in range(len(scene.gt)):
        assert _iou(index == i + 1, instances == i) > 0.95, i


@needs_bpy
def test_an_interrupted_run_resumes_its_unfinished_scenes_and_ends_as_a_fresh_run(tmp_path: Path, monkeypatch,
                                                                                  capsys) -> None:  # fmt: skip
    import cycles_scene

    src = method_data.build(tmp_path / "src", n_scenes=2)
    cheap = ["--samples", "1", "--no-denoise", "--threads", "2"]
    args = [str(src), str(tmp_path / "dst"), "--split", "real", *cheap]
    fresh = tmp_path / "fresh"
    assert rerender_cycles.main([str(src), str(fresh), "--split", "real", *cheap]) == 0
    render, calls = cycles_scene.CyclesScene.render, []

    def failing(self, view, seed):
        calls.append(view.im_id)
        if len(calls) == len(method_data.VIEWPOINTS) + 2:  # in the second scene
            raise RuntimeError("disk full")
        return render(self, view, seed)

    monkeypatch.setattr(cycles_scene.CyclesScene, "render", failing)
    assert rerender_cycles.main(args) == 2
    assert "disk full" in capsys.readouterr().err
    partial = tmp_path / "dst.partial"
    assert partial.is_dir() and not (tmp_path / "dst").exists()
    assert not list(partial.rglob("*.tmp"))  # nothing half-written
    monkeypatch.setattr(cycles_scene.CyclesScene, "render", render)
    assert rerender_cycles.main(args) == 2  # not without --resume
    assert "--resume" in capsys.readouterr().err
    assert rerender_cycles.main([*args, "--resume", "--samples", "3"]) == 2  # not with other settings
    assert "samples was 1, now 3" in capsys.readouterr().err
    calls.clear()
    monkeypatch.setattr(cycles_scene.CyclesScene, "render", failing)
    assert rerender_cycles.main([*args, "--resume"]) == 0
    assert len(calls) == len(method_data.VIEWPOINTS)  # the first scene was kept
    assert "done in an earlier run" in capsys.readouterr().out
    assert _images(tmp_path / "dst") == _images(fresh)
    assert not (tmp_path / "dst" / rerender_cycles.STATE).exists()


@pytest.fixture
def fake_bpy(monkeypatch) -> None:
    """A stand-in ``bpy``: the script's checks before any rendering run without Blender."""
    monkeypatch.setitem(sys.modules, "bpy", types.ModuleType("bpy"))
    monkeypatch.setitem(sys.modules, "_cycles", types.SimpleNamespace(with_openimagedenoise=True))


def test_a_skewed_camera_is_refused_naming_the_file_and_nothing_is_written(tmp_path: Path, fake_bpy, capsys) -> None:
    src = method_data.build(tmp_path / "src", n_scenes=1)
    for path in src.rglob("scene_camera.json"):
        cameras = json.loads(path.read_text())
        for entry in cameras.values():
            entry["cam_K"][1] = 5.0
        path.write_text(json.dumps(cameras))
    assert rerender_cycles.main([str(src), str(tmp_path / "dst"), "--split", "real"]) == 2
    err = capsys.readouterr().err
    assert "skew 5" in err and "scene_camera.json" in err and err.count("\n") == 1
    assert not (tmp_path / "dst").exists() and not (tmp_path / "dst.partial").exists()


def test_a_dataset_the_loader_refuses_is_one_line_and_nothing_is_written(tmp_path: Path, fake_bpy, capsys) -> None:
    src = method_data.build(tmp_path / "src", n_scenes=1)
    (src / "models" / "models_info.json").write_text("{")
    assert rerender_cycles.main([str(src), str(tmp_path / "dst"), "--split", "real"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "models_info.json" in err and err.count("\n") == 1
    assert not (tmp_path / "dst").exists() and not (tmp_path / "dst.partial").exists()


def test_an_unreadable_image_is_refused_before_anything_is_written(tmp_path: Path, fake_bpy, capsys) -> None:
    src = method_data.build(tmp_path / "src", n_scenes=1)
    image = sorted(src.rglob("rgb/*.png"))[1]
    image.write_bytes(b"not an image")
    assert rerender_cycles.main([str(src), str(tmp_path / "dst"), "--split", "real"]) == 2
    err = capsys.readouterr().err
    assert str(image) in err and err.count("\n") == 1
    assert not (tmp_path / "dst.partial").exists()


def test_without_bpy_one_line_how_to_install_and_exit_2(tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.setitem(sys.modules, "bpy", None)  # import fails
    assert rerender_cycles.main([str(tmp_path), str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: bpy is not usable here") and "pip install bpy==4.2.0" in err
    assert err.count("\n") == 1 and not (tmp_path / "out").exists()


def test_an_existing_destination_is_refused(tmp_path: Path, fake_bpy, capsys) -> None:
    (tmp_path / "out").mkdir()
    assert rerender_cycles.main([str(tmp_path), str(tmp_path / "out")]) == 2
    assert "exists" in capsys.readouterr().err


def test_the_blender_camera_of_a_pinhole() -> None:
    K = np.array([[500.0, 0.0, 160.0], [0.0, 500.0, 128.0], [0.0, 0.0, 1.0]])
    centred = cycles_look.blender_camera(K, 320, 256)
    assert centred["lens"] == pytest.approx(500.0 * cycles_look.SENSOR_WIDTH / 320)
    assert centred["shift_x"] == centred["shift_y"] == 0.0
    assert centred["pixel_aspect_x"] == centred["pixel_aspect_y"] == 1.0
    # principal point right of and below the centre: the image window moves left (-x) and up (+y, Blender's y)
    off = cycles_look.blender_camera(K + np.array([[0, 0, 32.0], [0, 0, 16.0], [0, 0, 0]]), 320, 256)
    assert off["shift_x"] == pytest.approx(-0.1) and off["shift_y"] == pytest.approx(0.05)
    with pytest.raises(cycles_look.SkewError, match="skew"):
        cycles_look.blender_camera(K + np.array([[0, 0.5, 0], [0, 0, 0], [0, 0, 0]]), 320, 256)


def test_the_support_plane_is_under_the_pile_or_absent_when_cameras_surround_it() -> None:
    rng = np.random.default_rng(0)
    points = rng.uniform([-100, -100, 0], [100, 100, 40], size=(500, 3))
    points[:4, 2] = 0.0  # the pile's lowest points rest on z = 0
    ring = np.array([[400 * np.cos(a), 400 * np.sin(a), 300.0] for a in np.linspace(0, 2 * np.pi, 8)])
    point, up = cycles_look.support_plane(points, ring, margin=0.5)
    np.testing.assert_allclose(up, [0, 0, 1], atol=1e-6)
    assert point[2] == pytest.approx(-0.5)
    assert cycles_look.support_plane(points, np.concatenate([ring, -ring])) is None


def test_the_looks_are_drawn_from_the_seed_metal_for_dimo_plastic_for_tless() -> None:
    a = cycles_look.draw_look(rerender_cycles._rng(7, "000001_00"), "dimo")
    assert a == cycles_look.draw_look(rerender_cycles._rng(7, "000001_00"), "dimo")
    assert a != cycles_look.draw_look(rerender_cycles._rng(8, "000001_00"), "dimo")
    looks = [cycles_look.draw_look(np.random.default_rng(s), layout) for s in range(20) for layout in ("dimo", "tless")]
    assert {look.target_metallic for look in looks[::2]} == {1.0}  # DIMO: metal
    assert {look.target_metallic for look in looks[1::2]} == {0.0}  # T-LESS: plastic
    assert all(1 <= len(look.lamps) <= 2 and look.table in cycles_look.TABLES for look in looks)
    assert {look.sky for look in looks} == {True, False}
