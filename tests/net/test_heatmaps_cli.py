"""``bop-cender heatmaps`` and ``bop-cender train`` from the command line: files, figures, one-line errors."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).parents[1]))
import method_data  # noqa: E402

from bop_cender.cli import main  # noqa: E402
from bop_cender.net.targets import TargetConfig  # noqa: E402
from bop_cender.net.unet import UNet, UNetSpec  # noqa: E402
from bop_cender.net.weights import save_weights, weights_payload  # noqa: E402


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    return method_data.build(tmp_path_factory.mktemp("hm") / "dimo")


@pytest.fixture(scope="module")
def weights(tmp_path_factory) -> Path:
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("w") / "w.pt"
    save_weights(
        path, weights_payload(UNet(UNetSpec.dimo_lean(width=0.5)), "dimo", None, TargetConfig.for_dataset("dimo"))
    )
    return path


def test_oracle_heatmaps_score_one_and_write_their_pngs(root, tmp_path, capsys) -> None:
    out = tmp_path / "hm"
    code = main(["heatmaps", "--dataset", "dimo", "--data-root", str(root), "--split", "real", "--weights", "oracle",
                 "--png", "--out", str(out), "--no-progress"])  # fmt: skip
    printed = capsys.readouterr().out
    assert code == 0 and "center_f1           1.000" in printed and "curvature_ap        1.000" in printed
    report = json.loads((out / "heatmaps_dimo-real.json").read_text())
    assert report["views"] == len(method_data.VIEWPOINTS) and report["metrics"]["center_f1"] == 1.0
    pngs = sorted((out / "png").glob("*.png"))
    assert len(pngs) == len(method_data.VIEWPOINTS) and pngs[0].read_bytes()[:4] == b"\x89PNG"
    stale = out / "png" / f"{pngs[0].stem.rpartition('_')[0]}_000099.png"  # a view the earlier report listed
    stale.write_bytes(pngs[0].read_bytes())
    report["pngs"].append(stale.name)
    (out / "heatmaps_dimo-real.json").write_text(json.dumps(report))
    other = out / "png" / "000000_00_000000.png"  # not in this split's report (another split's): kept
    other.write_bytes(pngs[0].read_bytes())
    code = main(["heatmaps", "--dataset", "dimo", "--data-root", str(root), "--split", "real", "--weights", "oracle",
                 "--png", "--out", str(out), "--no-progress"])  # fmt: skip
    assert code == 0 and "removed 1 PNG(s) of an earlier run" in capsys.readouterr().out
    assert sorted((out / "png").glob("*.png")) == sorted([*pngs, other])


def test_network_heatmaps_report_their_time_and_figures(root, weights, tmp_path, capsys) -> None:
    out = tmp_path / "hm"
    code = main(["heatmaps", "--dataset", "dimo", "--data-root", str(root), "--split", "real", "--weights",
                 str(weights), "--out", str(out), "--no-progress"])  # fmt: skip
    assert code == 0
    report = json.loads((out / "heatmaps_dimo-real.json").read_text())
    assert report["ms_per_view"] > 0 and report["source"] == str(weights)
    assert report["metrics"]["center_recall"] < 1.0  # an untrained network finds nothing
    assert "ms per view" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "field"),
    [
        (["heatmaps", "--weights", "missing.pt"], "not found"),
        (["heatmaps", "--weights", "oracle", "--limit-scenes", "0"], "--limit-scenes"),
        (["heatmaps", "--weights", "oracle", "--out", "afile"], "not a directory"),
        (["heatmaps", "--weights", "oracle", "--peak-threshold", "1.5"], "--peak-threshold"),
        (["heatmaps", "--weights", "oracle", "--test-flips", "4"], "--test-flips"),
        (["train", "--epochs", "0", "--out", "run"], "--epochs"),
        (["train", "--crop", "12by4", "--out", "run"], "--crop"),
        (["train", "--out", "afile"], "not a directory"),
        (["train", "--class-loss-weight", "0.5", "--out", "run"], "--class-loss-weight: weights the class loss of a"),
    ],
)
def test_bad_options_are_one_line(root, tmp_path, capsys, monkeypatch, argv, field) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("x")
    code = main([*argv, "--dataset", "dimo", "--data-root", str(root), "--split", "real", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: ") and err.count("\n") == 1 and field in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_train_from_the_command_line_writes_a_run(root, tmp_path, capsys) -> None:
    code = main(["train", "--dataset", "dimo", "--data-root", str(root), "--split", "real", "--epochs", "1",
                 "--width", "0.25", "--batch-size", "4", "--out", str(tmp_path / "run"), "--no-progress"])  # fmt: skip
    assert code == 0 and (tmp_path / "run" / "weights.pt").is_file()
    assert "trained 1 epoch" in capsys.readouterr().out
    again = ["train", "--dataset", "dimo", "--data-root", str(root), "--split", "real", "--width", "0.25",
             "--batch-size", "4", "--out", str(tmp_path / "run"), "--no-progress", "--resume"]  # fmt: skip
    weights = (tmp_path / "run" / "weights.pt").read_bytes()
    assert main([*again, "--epochs", "1"]) == 0  # a finished run's command again: said, nothing changed
    assert f"nothing to train: {tmp_path / 'run'} holds its 1 epochs already" in capsys.readouterr().out
    assert (tmp_path / "run" / "weights.pt").read_bytes() == weights


def test_run_with_network_weights_estimates_every_scene(root, weights, tmp_path, capsys, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    code = main(["run", "--dataset", "dimo", "--data-root", str(root), "--split", "real", "--weights", str(weights),
                 "--candidates", "16", "--top-k", "1", "--no-progress", "--deterministic-time"])  # fmt: skip
    captured = capsys.readouterr()
    assert code == 0, captured.err
    out = tmp_path / "cendernet-net_dimo-real.csv"
    assert out.is_file() and f"next: bop-cender score {out.name}" in captured.out
    sidecar = json.loads(next(tmp_path.glob("*.json")).read_text())
    assert sidecar["extra"]["weights"] == str(weights) and sidecar["extra"]["heatmaps"] == "net"


def test_a_failing_scene_leaves_no_pngs_behind(tmp_path, capsys) -> None:
    """Scene 000001 has an image that does not decode: the error names it, and the PNGs of scene 000000 written
    before it are removed (those of an earlier run in the same folder stay)."""
    root = method_data.build(tmp_path / "dimo", n_scenes=2)
    broken = sorted((root / "real_jaigo" / "000001" / "rgb").glob("*.png"))[0]
    broken.write_bytes(broken.read_bytes()[:200])
    argv = ["heatmaps", "--dataset", "dimo", "--data-root", str(root), "--split", "real", "--weights", "oracle",
            "--png", "--no-progress"]  # fmt: skip
    assert main([*argv, "--out", str(tmp_path / "new")]) == 2
    assert f"{broken}: cannot decode image" in capsys.readouterr().err and not (tmp_path / "new").exists()
    old = tmp_path / "old" / "png" / "earlier.png"
    old.parent.mkdir(parents=True)
    old.write_bytes(b"x")
    assert main([*argv, "--out", str(tmp_path / "old")]) == 2
    assert sorted(p.name for p in old.parent.iterdir()) == ["earlier.png"]


def test_weights_without_a_channel_for_an_object_of_the_dataset_are_refused(tmp_path, capsys) -> None:
    """One center channel per object (T-LESS kind): weights that lack a target object of the dataset could never
    find it; `heatmaps` printed figures of them with exit 0 (recall 1.0 beside 0 true positives)."""
    root = tmp_path / "tless"
    assert main(["synth", "--layout", "tless", "--out", str(root), "--scenes", "1", "--views", "2", "--pbr-scenes",
                 "0", "--seed", "5", "--no-contact-sheets"]) == 0  # fmt: skip
    path = tmp_path / "few.pt"
    spec = UNetSpec.tless_lean(center_channels=3, width=0.25)
    save_weights(path, weights_payload(UNet(spec), "tless", (1, 2, 5), TargetConfig.for_dataset("tless")))
    capsys.readouterr()
    data = ["--dataset", "tless", "--data-root", str(root), "--split", "test", "--weights", str(path), "--no-progress"]
    for argv in (
        ["heatmaps", *data, "--out", str(tmp_path / "hm")],
        ["run", *data, "--out", str(tmp_path / "m_tless-test.csv")],
    ):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"error: {path}: the weights have no center channel for object(s) [3, 4, 6,"), err
        assert err.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["few.pt", "tless"]
