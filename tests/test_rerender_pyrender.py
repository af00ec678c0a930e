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
    # the objects are where the GT says: the pyrender image differs from its plain background around them only
    view = after.scene(after.scene_keys[0]).views[0]
    image = np.asarray(Image.open(view.rgb_path)).astype(float)
    background = np.array([0.18, 0.2, 0.22]) * 255
    assert np.abs(image - background).max(-1).mean() > 10


@pytest.mark.skipif(not _pyrender_works(), reason="pyrender or an offscreen OpenGL context (EGL/OSMesa) is missing")
def test_a_tless_layout_gets_every_image_the_method_runs_on_rendered_again(tmp_path: Path) -> None:
    sys.path.insert(0, str(Path(__file__).parent / "data"))
    from bop_builder import BopSpec, build_bop

    built = build_bop(tmp_path / "src", BopSpec(n_scenes=1, n_images=4, pbr_scenes=0), models_dirs=("models_cad",))
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
