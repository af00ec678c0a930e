"""``scripts/rerender_pyrender.py``: a DIMO-layout copy whose images another renderer (pyrender) made, read by the
same loader; without pyrender, one clear line and exit 2."""

from __future__ import annotations

import filecmp
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

sys.path.insert(0, str(Path(__file__).parent))
sys.path.insert(0, str(Path(__file__).parents[1] / "scripts"))
import method_data  # noqa: E402
import rerender_pyrender  # noqa: E402

from bop_cender.data.dimo import DimoSelection, open_dimo  # noqa: E402
from bop_cender.data.registry import DatasetRequest, open_dataset  # noqa: E402


def _pyrender_works() -> bool:
    try:
        import pyrender

        pyrender.OffscreenRenderer(8, 8).delete()
        return True
    except Exception:
        return False


@pytest.mark.skipif(not _pyrender_works(), reason="pyrender or an offscreen OpenGL context (EGL/OSMesa) is missing")
def test_every_image_of_the_split_is_rendered_again_and_the_loader_reads_the_copy(tmp_path: Path) -> None:
    src = method_data.build(tmp_path / "src", n_scenes=2)
    dst = tmp_path / "dst"
    assert rerender_pyrender.main([str(src), str(dst), "--split", "real", "--seed", "1"]) == 0
    before = open_dimo(src, "real", DimoSelection.everything())
    after = open_dataset(DatasetRequest("dimo", dst, "real"))
    assert after.scene_keys == open_dataset(DatasetRequest("dimo", src, "real")).scene_keys
    for key in before.scene_keys:
        scene = before.scene(key)
        twin = after.scene(key)
        np.testing.assert_array_equal([g.T_world_model for g in twin.gt], [g.T_world_model for g in scene.gt])
        for view in scene.views:  # every image, the paper's selection or not
            copy = dst / Path(view.rgb_path).relative_to(src)
            ours, theirs = np.asarray(Image.open(view.rgb_path)), np.asarray(Image.open(copy))
            assert theirs.shape == ours.shape and np.abs(theirs.astype(int) - ours.astype(int)).mean() > 5
    # everything else is copied as it was
    for json_file in src.rglob("*.json"):
        assert filecmp.cmp(json_file, dst / json_file.relative_to(src), shallow=False)
    assert not (tmp_path / "dst.partial").exists()
    # the objects are where the GT says: pyrender's foreground is our renderer's silhouette of the same scene
    scene = after.scene(after.scene_keys[0])
    for view in scene.views[:2]:
        assert _silhouette_iou(scene, view, after) > 0.9


def _silhouette_iou(scene, view, dataset) -> float:
    """IoU of the pixels of ``view``'s image unlike the flat background and our renderer's silhouette of the scene's
    objects at their GT poses (a flipped axis or a shifted principal point would not reach 0.9)."""
    foreground, silhouette = _masks(scene, view, dataset)
    return float((foreground & silhouette).sum() / max(1, (foreground | silhouette).sum()))


def _masks(scene, view, dataset) -> tuple[np.ndarray, np.ndarray]:
    """``(H, W)`` bool: where ``view``'s image is unlike the flat background, and our renderer's silhouette there."""
    import torch

    from bop_cender.meshes import MeshCache
    from bop_cender.render.rasterizer import render_scene

    meshes = MeshCache(dataset.models)
    T = np.stack([view.T_cam_world @ g.T_world_model for g in scene.gt])[None]
    K = torch.as_tensor(view.K, dtype=torch.float32)[None]
    depth = render_scene([meshes(g.obj_id) for g in scene.gt], torch.as_tensor(T, dtype=torch.float32), K,
                         int(view.height), int(view.width)).depth[0].numpy()  # fmt: skip
    image = np.asarray(Image.open(view.rgb_path)).astype(float)
    return np.abs(image - np.array([0.18, 0.2, 0.22]) * 255).max(-1) > 25, depth > 0


@pytest.mark.skipif(not _pyrender_works(), reason="pyrender or an offscreen OpenGL context (EGL/OSMesa) is missing")
def test_a_tless_layout_gets_every_image_the_method_runs_on_rendered_again(tmp_path: Path) -> None:
    sys.path.insert(0, str(Path(__file__).parent / "data"))
    from bop_builder import BopSpec, build_bop

    built = build_bop(
        tmp_path / "src",
        BopSpec(n_scenes=1, n_images=4, pbr_scenes=0, image_size=(160, 120)),
        models_dirs=("models_cad",),
    )
    dst = tmp_path / "dst"
    assert rerender_pyrender.main([str(built.root), str(dst), "--dataset", "tless"]) == 0
    src_ds = open_dataset(DatasetRequest("tless", built.root, "test", n_views=1))
    dst_ds = open_dataset(DatasetRequest("tless", dst, "test", n_views=1))
    assert dst_ds.scene_keys == src_ds.scene_keys
    for key in src_ds.scene_keys:
        (view,) = src_ds.scene(key).views
        ours = np.asarray(Image.open(view.rgb_path)).astype(int)
        theirs = np.asarray(Image.open(dst / Path(view.rgb_path).relative_to(built.root))).astype(int)
        assert theirs.shape == ours.shape and np.abs(theirs - ours).mean() > 5
        # the builder's objects are a few pixels wide here: pyrender draws at least where ours does
        foreground, silhouette = _masks(dst_ds.scene(key), dst_ds.scene(key).views[0], dst_ds)
        assert silhouette.sum() > 0 and (foreground & silhouette).sum() >= 0.8 * silhouette.sum()


@pytest.mark.skipif(not _pyrender_works(), reason="pyrender or an offscreen OpenGL context (EGL/OSMesa) is missing")
def test_a_skewed_camera_is_refused_and_nothing_is_left(tmp_path: Path, capsys) -> None:
    import json

    src = method_data.build(tmp_path / "src", n_scenes=1)
    for path in src.rglob("scene_camera.json"):
        cameras = json.loads(path.read_text())
        for entry in cameras.values():
            entry["cam_K"][1] = 5.0  # skew: pyrender's pinhole cannot render it
        path.write_text(json.dumps(cameras))
    assert rerender_pyrender.main([str(src), str(tmp_path / "dst"), "--split", "real"]) == 2
    err = capsys.readouterr().err
    assert "skew" in err and err.count("\n") == 1
    assert not (tmp_path / "dst").exists() and not (tmp_path / "dst.partial").exists()


def test_without_pyrender_one_line_and_exit_2(tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.setitem(sys.modules, "pyrender", None)  # import fails
    assert rerender_pyrender.main([str(tmp_path), str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: pyrender is not usable here") and err.count("\n") == 1
    assert not (tmp_path / "out").exists()


@pytest.mark.skipif(not _pyrender_works(), reason="pyrender or an offscreen OpenGL context (EGL/OSMesa) is missing")
def test_an_existing_destination_is_refused(tmp_path: Path, capsys) -> None:
    (tmp_path / "out").mkdir()
    assert rerender_pyrender.main([str(tmp_path), str(tmp_path / "out")]) == 2
    assert "exists" in capsys.readouterr().err


def test_a_negative_noise_or_no_scene_is_one_error(tmp_path: Path, capsys) -> None:
    """Before any work: an empty copy written with exit 0 would read as a look of no scene."""
    for flag, value in (("--limit-scenes", "0"), ("--noise", "-1")):
        assert rerender_pyrender.main([str(tmp_path), str(tmp_path / "dst"), flag, value]) == 2
        assert f"error: {flag}: expected" in capsys.readouterr().err and not (tmp_path / "dst").exists()
