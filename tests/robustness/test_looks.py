"""The robustness benchmark's looks: the foreign camera (``synth/sensor_look.py``), the copies of a split in another
look (``synth/relook.py``) and the benchmark's table (``scripts/robustness.py``)."""

from __future__ import annotations

import csv
import filecmp
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

sys.path.insert(0, str(Path(__file__).parents[1]))
sys.path.insert(0, str(Path(__file__).parents[2] / "scripts"))
import method_data  # noqa: E402
import robustness  # noqa: E402

from bop_cender.data.dimo import DimoSelection, open_dimo  # noqa: E402
from bop_cender.data.registry import DatasetRequest, open_dataset  # noqa: E402
from bop_cender.synth.relook import open_every_image, relook_split, sensor_redraw  # noqa: E402
from bop_cender.synth.sensor_look import SensorLook, _bayer_demosaic, _pillbox_blur, apply_sensor_look, look_rng  # noqa: E402


def _image(seed: int = 0, shape=(48, 64, 3)) -> np.ndarray:
    return (np.random.default_rng(seed).random(shape) * 255).astype(np.uint8)


def test_the_foreign_camera_is_deterministic_per_seed_and_name_and_changes_the_image() -> None:
    image = _image()
    outs = []
    for seed, name in ((1, "a.png"), (1, "a.png"), (2, "a.png"), (1, "b.png")):
        rng = look_rng(seed, name)
        outs.append(apply_sensor_look(image, SensorLook.draw(rng), rng))
    assert outs[0].shape == image.shape and outs[0].dtype == np.uint8
    np.testing.assert_array_equal(outs[0], outs[1])
    assert not np.array_equal(outs[0], outs[2]) and not np.array_equal(outs[0], outs[3])
    assert np.abs(outs[0].astype(int) - image.astype(int)).mean() > 10


def test_its_draws_lie_outside_the_training_ranges() -> None:
    """Exposure outside the augmentations' brightness 0.7-1.3, a disc blur of at least a pixel, JPEG quality <= 60."""
    for seed in range(200):
        look = SensorLook.draw(np.random.default_rng(seed))
        assert look.exposure <= 0.6 or look.exposure >= 1.6
        assert 1.0 <= look.defocus_px <= 2.5 and 35 <= look.jpeg_quality <= 60 and look.white_balance[1] == 1.0


def test_a_grey_image_stays_grey_and_bad_images_are_refused() -> None:
    rng = look_rng(0, "g.png")
    assert apply_sensor_look(_image(shape=(32, 40)), SensorLook.draw(rng), rng).shape == (32, 40)
    for bad in (np.zeros((8, 8, 4), np.uint8), np.zeros((8, 8), np.float32), np.zeros(8, np.uint8)):
        with pytest.raises(ValueError, match="uint8"):
            apply_sensor_look(bad, SensorLook.draw(rng), rng)


def test_blur_and_demosaic_keep_a_flat_image_and_the_demosaic_keeps_each_measured_sample() -> None:
    import torch

    flat = torch.full((3, 20, 30), 0.4)
    torch.testing.assert_close(_pillbox_blur(flat, 2.3), flat)
    torch.testing.assert_close(_bayer_demosaic(flat), flat)
    rgb = torch.rand(3, 20, 30)
    out = _bayer_demosaic(rgb)
    assert torch.equal(out[0, ::2, ::2], rgb[0, ::2, ::2]) and torch.equal(out[2, 1::2, 1::2], rgb[2, 1::2, 1::2])
    assert not torch.equal(out, rgb)


def test_a_split_in_the_sensor_look_is_a_copy_with_only_its_images_redrawn(tmp_path: Path) -> None:
    src = method_data.build(tmp_path / "src", n_scenes=1)
    dst = tmp_path / "dst"
    n = relook_split(open_every_image("dimo", src, "real"), src, dst, sensor_redraw(3))
    before = open_dimo(src, "real", DimoSelection.everything())
    assert n == sum(len(before.scene(k).views) for k in before.scene_keys) > 0
    for key in before.scene_keys:
        for view in before.scene(key).views:
            copy = dst / Path(view.rgb_path).relative_to(src)
            ours, theirs = np.asarray(Image.open(view.rgb_path)), np.asarray(Image.open(copy))
            assert theirs.shape == ours.shape and np.abs(theirs.astype(int) - ours.astype(int)).mean() > 5
    for json_file in src.rglob("*.json"):
        assert filecmp.cmp(json_file, dst / json_file.relative_to(src), shallow=False)
    assert open_dataset(DatasetRequest("dimo", dst, "real")).scene_keys == before.scene_keys
    assert not (tmp_path / "dst.partial").exists()
    with pytest.raises(FileExistsError):
        relook_split(open_every_image("dimo", src, "real"), src, dst, sensor_redraw(3))


def test_a_relook_that_fails_midway_leaves_nothing(tmp_path: Path) -> None:
    src = method_data.build(tmp_path / "src", n_scenes=1)
    calls = []

    def broken(scene, view, name: str) -> np.ndarray:
        calls.append(name)
        if len(calls) == 3:
            raise OSError("disk full")
        return np.zeros((int(view.height), int(view.width), 3), np.uint8)

    with pytest.raises(OSError, match="disk full"):
        relook_split(open_every_image("dimo", src, "real"), src, tmp_path / "dst", broken)
    assert not (tmp_path / "dst").exists() and not (tmp_path / "dst.partial").exists()


def test_the_table_gives_each_look_its_drop_from_the_own_look() -> None:
    rows = [
        {"look": "own", "split": "sim", "AR_MSSD<5%": 0.8},
        {"look": "sensor", "split": "sim", "AR_MSSD<5%": 0.6},
        {"look": "own", "split": "real", "AR_MSSD<5%": 0.5},
        {"look": "sensor", "split": "real", "AR_MSSD<5%": 0.5},
    ]
    lines = robustness.table(rows, ["AR_MSSD<5%"], ["own", "sensor"], ["sim", "real"])
    assert lines[0] == "| look | sim AR_MSSD<5% | drop | real AR_MSSD<5% | drop |"
    assert lines[2] == "| own | 0.800 |  | 0.500 |  |"
    assert lines[3] == "| sensor | 0.600 | -0.200 (-25 %) | 0.500 | +0.000 (+0 %) |"
    two = [
        {"look": "own", "split": "sim", "a": 0.5, "b": 0.0},
        {"look": "pyrender", "split": "sim", "a": 0.4, "b": 0.1},
    ]
    lines = robustness.table(two, ["a", "b"], ["own", "pyrender"], ["sim"])
    assert lines[0] == "| look | sim a | drop | sim b | drop |" and lines[1] == "|---|---:|---:|---:|---:|"
    assert lines[3] == "| pyrender | 0.400 | -0.100 (-20 %) | 0.100 |  |"  # no drop from an own figure of 0


def test_the_heatmap_measure_scores_stage_one_per_look_and_keeps_its_reports(tmp_path: Path) -> None:
    """``--measure heatmaps`` with oracle maps: every look's centre F1 and curvature AP are 1 (a look changes no
    ground truth), written to the table and CSV; a second call reads the kept reports and runs nothing."""
    src = method_data.build(tmp_path / "src", n_scenes=1)
    out = tmp_path / "out"
    args = ["--dataset", "dimo", "--data-root", str(src), "--splits", "real", "--looks", "own,sensor", "--heatmaps",
            "oracle", "--measure", "heatmaps", "--out", str(out)]  # fmt: skip
    assert robustness.main(args) == 0
    with open(out / "robustness.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["look"] for r in rows] == ["own", "sensor"]
    assert all(float(r["centre F1"]) == 1.0 and float(r["curvature AP"]) > 0.99 for r in rows)
    assert (out / "robustness.md").read_text().startswith("| look | real centre F1 | drop | real curvature AP | drop |")
    (out / "heatmaps-oracleown_dimo-real" / "heatmaps_dimo-real.json").write_text("{")
    assert robustness.main(args) == 2  # a damaged report is one error, not a traceback


def test_an_unknown_look_or_a_missing_data_root_is_one_error(tmp_path: Path, capsys) -> None:
    out = tmp_path / "out"
    assert (
        robustness.main(["--dataset", "dimo", "--data-root", str(tmp_path), "--looks", "own,foggy", "--out", str(out)])
        == 2
    )
    assert "--looks: unknown look foggy" in capsys.readouterr().err
    assert robustness.main(["--dataset", "dimo", "--data-root", str(tmp_path / "no"), "--out", str(out)]) == 2
    assert "--data-root" in capsys.readouterr().err and not out.exists()


def test_an_empty_split_or_a_limit_below_one_is_one_error(tmp_path: Path, capsys) -> None:
    out = tmp_path / "out"
    base = ["--dataset", "dimo", "--data-root", str(tmp_path), "--out", str(out)]
    assert robustness.main([*base, "--splits", "sim,"]) == 2
    assert "--splits: an empty split name in 'sim,'" in capsys.readouterr().err
    assert robustness.main([*base, "--measure", "heatmaps", "--heatmaps", "oracle-centers"]) == 2
    assert "--measure heatmaps measures the network or the oracle" in capsys.readouterr().err
    assert robustness.main([*base, "--limit-scenes", "0"]) == 2
    assert "--limit-scenes: expected 1 or more, got 0" in capsys.readouterr().err and not out.exists()
