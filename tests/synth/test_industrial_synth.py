"""``bop-cender synth --layout industrial``: a tiny multi-sensor bin-picking set, read back by the project's reader.

One set (one test scene and one train scene of two captures, small images) is written once per module (about a
minute on two busy cores); the tests read it, and one deletes a scene folder and resumes (same bytes again).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from bop_cender.cli import main
from bop_cender.data.industrial_params import SYNTH_INDUSTRIAL
from bop_cender.data.industrial_scene import VIEW_ID_STRIDE
from bop_cender.data.registry import DatasetRequest, open_dataset
from bop_cender.synth.generate import generate
from bop_cender.synth.write_industrial import IndustrialSynthSpec

SPEC = IndustrialSynthSpec(n_scenes=1, n_images=2, train_scenes=1, parts_per_scene=(10, 12), seed=3)
SENSORS = [(s.name, s.modalities, s.image_size) for s in SYNTH_INDUSTRIAL.sensors]


def _hashes(root: Path) -> dict[str, str]:
    """Every file under ``root`` (the generator's record, whose ``complete`` flag is rewritten, aside) -> sha1."""
    return {
        p.relative_to(root).as_posix(): hashlib.sha1(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file() and p.name != "bop_cender_synth.json"
    }


@pytest.fixture(scope="module")
def bins(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("synth") / "bins"  # any folder name: the record tells the reader
    report = generate("industrial", root, SPEC, progress=False)
    assert (report.written, report.skipped) == (2, 0) and report.targets
    return root


def test_the_reader_opens_every_sensor_at_its_size_and_modality(bins: Path) -> None:
    ds = open_dataset(DatasetRequest("bop", root=bins, split="test"))
    assert ds.eval_sensor == "hires" and [(s.name, s.modalities, s.image_size) for s in ds.sensors] == SENSORS
    assert ds.scene_keys == ["000001/i000000", "000001/i000001"] and sorted(ds.models) == [1, 2, 3, 4, 5, 6]
    assert (bins / "models_eval" / "models_info.json").is_file() and ds.bop19_targets
    for key in ds.scene_keys:
        scene = ds.scene(key)
        im = int(key[-6:])
        assert scene.im_ids == [k * VIEW_ID_STRIDE + im for k in range(4)]
        assert [v.evaluated for v in scene.views] == [True, False, False, False]
        for view, (name, modalities, (w, h)) in zip(scene.views, SENSORS, strict=True):
            image = cv2.imread(str(view.rgb_path), cv2.IMREAD_UNCHANGED)
            channels = 1 if image.ndim == 2 else image.shape[2]
            assert view.sensor == name and image.shape[:2] == (h, w) == (view.height, view.width)
            assert channels == (3 if "rgb" in modalities else 1)
            assert (view.depth_path is not None) == ("depth" in modalities)
            assert len(view.mask_visib_paths) == len(scene.gt)
            assert cv2.imread(str(view.mask_visib_paths[0]), cv2.IMREAD_UNCHANGED).shape == (h, w)
        depth = cv2.imread(str(scene.views[3].depth_path), cv2.IMREAD_UNCHANGED)
        assert depth.dtype == np.uint16 and depth.max() > 0
        # a dense bin: every part is one GT instance seen by all four sensors, at one world pose (the reader
        # associates them across sensors and checks that their camera poses agree)
        assert 10 <= len(scene.gt) <= 12 and all(len(g.gt_ids) == 4 for g in scene.gt)
        fracts = [f for g in scene.gt for f in g.visib_fract.values()]
        assert all(0.0 <= f <= 1.0 for f in fracts) and min(fracts) < 0.9 and max(fracts) > 0.5  # parts occlude
    assert ds.residuals["gt_max_mm"] < 1e-3


def test_gt_per_sensor_is_one_world_pose(bins: Path) -> None:
    scene_dir = bins / "test" / "000001"
    world = {}
    for name, _, _ in SENSORS:
        cams = json.loads((scene_dir / f"scene_camera_{name}.json").read_text())
        gts = json.loads((scene_dir / f"scene_gt_{name}.json").read_text())
        info = json.loads((scene_dir / f"scene_gt_info_{name}.json").read_text())
        assert sorted(cams) == sorted(gts) == sorted(info) == ["0", "1"]
        for im, entries in gts.items():
            T_cw = np.eye(4)
            T_cw[:3, :3] = np.reshape(cams[im]["cam_R_w2c"], (3, 3))
            T_cw[:3, 3] = cams[im]["cam_t_w2c"]
            for gt_id, e in enumerate(entries):
                T_cm = np.eye(4)
                T_cm[:3, :3], T_cm[:3, 3] = np.reshape(e["cam_R_m2c"], (3, 3)), e["cam_t_m2c"]
                T_wm = np.linalg.inv(T_cw) @ T_cm
                ref = world.setdefault(gt_id, (e["obj_id"], T_wm))
                assert ref[0] == e["obj_id"] and np.allclose(ref[1], T_wm, atol=1e-6)
                assert 0.0 <= info[im][gt_id]["visib_fract"] <= 1.0


def test_targets_name_the_evaluated_sensors_visible_parts(bins: Path) -> None:
    targets = json.loads((bins / "test_targets_bop19.json").read_text())
    bop24 = json.loads((bins / "test_targets_bop24.json").read_text())
    assert (
        {(t["scene_id"], t["im_id"]) for t in targets}
        == {(1, 0), (1, 1)}
        == {(t["scene_id"], t["im_id"]) for t in bop24}
    )
    gts = json.loads((bins / "test" / "000001" / "scene_gt_hires.json").read_text())
    info = json.loads((bins / "test" / "000001" / "scene_gt_info_hires.json").read_text())
    for im in (0, 1):
        visible = [g["obj_id"] for g, i in zip(gts[str(im)], info[str(im)], strict=True) if i["visib_fract"] >= 0.1]
        assert {t["obj_id"]: t["inst_count"] for t in targets if t["im_id"] == im} == {
            o: visible.count(o) for o in set(visible)}  # fmt: skip


def test_train_split_and_info_command(bins: Path, capsys) -> None:
    train = open_dataset(DatasetRequest("bop", root=bins, split="train"))
    assert train.scene_keys == ["000000/i000000", "000000/i000001"] and len(train.scene(train.scene_keys[0]).views) == 4
    assert main(["info", "--dataset", "bop", "--data-root", str(bins), "--split", "test"]) == 0
    out = capsys.readouterr().out
    assert "hires" in out and "2" in out
    sheets = sorted(p.name for p in (bins / "contact_sheets").iterdir())
    assert sheets == ["test_000001.png", "train_000000.png"]


def test_a_resume_keeps_done_scenes_and_rewrites_the_same_bytes(bins: Path) -> None:
    before = _hashes(bins)
    kept = (bins / "test" / "000001" / "scene_gt_hires.json").stat().st_mtime_ns
    report = generate("industrial", bins, SPEC, progress=False)  # all done: nothing written
    assert (report.written, report.skipped) == (0, 2)
    # a scene folder lost: the resume writes it again, byte for byte (same seed, same bytes), and keeps the other
    for p in sorted((bins / "train" / "000000").rglob("*"), reverse=True):
        p.unlink() if p.is_file() else p.rmdir()
    (bins / "train" / "000000").rmdir()
    report = generate("industrial", bins, SPEC, progress=False)
    assert (report.written, report.skipped) == (1, 1)
    assert (bins / "test" / "000001" / "scene_gt_hires.json").stat().st_mtime_ns == kept
    assert _hashes(bins) == before


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--parts", "12"], "expected MIN,MAX"),
        (["--parts", "9,3"], "1 <= MIN <= MAX"),
        (["--pbr-scenes", "1"], "is a tless option"),
        (["--variants", "0"], "is a dimo option"),
    ],
)
def test_bad_options_are_one_error(tmp_path: Path, capsys, extra: list[str], message: str) -> None:
    out = tmp_path / "bins"
    code = main(["synth", "--layout", "industrial", "--out", str(out), "--scenes", "1", *extra])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: ") and message in err and len(err.strip().splitlines()) == 1
    assert not (out / "test").exists()


def test_the_method_runs_across_cameras_of_several_sizes_and_writes_the_evaluated_sensors_rows(
    bins: Path, tmp_path: Path, capsys
) -> None:
    """``run --dataset bop`` on the multi-sensor set: every camera at the evaluated one's size (K scaled, image
    resampled: bop_cender/data/canvas.py), rows for the evaluated sensor only, ``score`` with no flag (BOP'24)."""
    from bop_cender.data.canvas import RESAMPLED_FROM, on_one_canvas, read_view_rgb
    from bop_cender.results.bop_csv import read_bop_results

    scene = open_dataset(DatasetRequest("bop", root=bins, split="test")).scene("000001/i000000")
    seen = on_one_canvas(scene)
    W, H = scene.views[0].width, scene.views[0].height
    assert seen.views[0] is scene.views[0] and all((v.width, v.height) == (W, H) for v in seen.views)
    for before, after in zip(scene.views[1:], seen.views[1:], strict=True):
        sx, sy = W / before.width, H / before.height
        assert np.allclose(after.K, np.diag([sx, sy, 1.0]) @ before.K) and after.info[RESAMPLED_FROM] == (
            before.width, before.height
        )  # fmt: skip
        assert read_view_rgb(after).shape == (H, W, 3) and np.array_equal(after.T_cam_world, before.T_cam_world)
    out = tmp_path / "cendernet-oracle_bins-test.csv"
    argv = ["run", "--dataset", "bop", "--data-root", str(bins), "--split", "test", "--heatmaps", "oracle",
            "--task", "detection", "--out", str(out), "--limit-scenes", "1", "--candidates", "48", "--top-k", "1",
            "--deterministic-time", "--no-progress"]  # fmt: skip
    assert main(argv) == 0
    rows = read_bop_results(out)
    assert rows and {(r.scene_id, r.im_id) for r in rows} == {(1, 0)}  # the evaluated sensor's image only
    assert main(["score", str(out), "--no-progress"]) == 0
    assert "bop25_mAP_mm" in capsys.readouterr().out


def test_a_multi_sensor_folder_gets_the_bin_picking_centre_targets(bins: Path, tmp_path: Path) -> None:
    """A blob from 10 % visible, s_e 0.5 (T-LESS's 50 % left most parts of a bin without one: oracle bop25_mAP 0.395
    against 0.893, results/accuracy/industrial/README.md); a classic BOP folder keeps T-LESS's."""
    from bop_cender.data.industrial import config_layout
    from bop_cender.method import CenDerNetConfig

    assert (
        config_layout("bop", str(bins), "test") == "industrial" and config_layout("tless", str(bins), "test") == "tless"
    )
    assert config_layout("bop", str(tmp_path), "test") == "bop" and config_layout("bop", None, "test") == "bop"
    targets = CenDerNetConfig.for_dataset("industrial").targets
    assert (targets.min_visib_fract, targets.s_e, targets.per_object_channels) == (0.1, 0.5, True)
    assert CenDerNetConfig.for_dataset("ipd").targets == targets
    assert CenDerNetConfig.for_dataset("bop").targets.min_visib_fract == 0.5


def test_train_reads_the_multi_sensor_train_split_at_one_size_with_the_bin_targets(bins: Path, tmp_path: Path) -> None:
    """``train`` on the layout's train split: every camera of a capture at the evaluated one's size, the centre
    targets of bins (one place chooses them for run, train and heatmaps: data/industrial.py config_layout)."""
    from bop_cender.net.train import TrainConfig, train
    from bop_cender.net.weights import load_weights

    config = TrainConfig(dataset="bop", data_root=str(bins), split="train", epochs=1, batch_size=4,
                         variant="tless-lean", width=0.25, seed=1)  # fmt: skip
    result = train(config, tmp_path / "run", progress=False)
    assert result.epochs_done == 1
    weights = load_weights(tmp_path / "run" / "weights.pt")
    assert weights.targets.min_visib_fract == 0.1 and weights.targets.s_e == 0.5
    assert weights.channel_obj_ids == (1, 2, 3, 4, 5, 6)
