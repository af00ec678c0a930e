"""``scripts/calibrate_curvature.py``: the best-F1 threshold of validation views goes into the weights file, and
nothing else changes; a split without GT or a useless threshold is one error."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).parents[1]))
sys.path.insert(0, str(Path(__file__).parents[2] / "scripts"))
import calibrate_curvature  # noqa: E402
import method_data  # noqa: E402

from bop_cender.errors import ConfigError  # noqa: E402
from bop_cender.net.heatmap_eval import HeatmapReport  # noqa: E402
from bop_cender.net.targets import TargetConfig  # noqa: E402
from bop_cender.net.unet import UNet, UNetSpec  # noqa: E402
from bop_cender.net.weights import load_weights, save_weights, weights_payload  # noqa: E402


@pytest.fixture()
def setup(tmp_path, monkeypatch):
    root = method_data.build(tmp_path / "dimo")
    torch.manual_seed(0)
    weights = tmp_path / "w.pt"
    save_weights(weights, weights_payload(UNet(UNetSpec.dimo_lean(width=0.5)), "dimo", None,
                                          TargetConfig.for_dataset("dimo"), epoch=3))  # fmt: skip
    figures: dict = {}

    def fake_evaluate(data, predictor, targets, meshes, source, **kw):
        report = HeatmapReport("dimo", data.split, source, scenes=1, views=4)
        report.metrics = dict(figures)
        return report

    monkeypatch.setattr(calibrate_curvature, "evaluate_heatmaps", fake_evaluate)
    return root, weights, figures


def test_the_threshold_is_written_and_the_network_kept(setup, tmp_path, capsys) -> None:
    root, weights, figures = setup
    figures.update(curvature_f1=0.4, curvature_best_f1=0.6, curvature_best_threshold=0.62, curvature_ap=0.5)
    out = tmp_path / "cal.pt"
    code = calibrate_curvature.main([str(weights), "--dataset", "dimo", "--data-root", str(root), "--split", "real",
                                     "--out", str(out)])  # fmt: skip
    assert code == 0 and "0.400 at t_b, 0.600 at 0.620" in capsys.readouterr().out
    before, after = load_weights(weights), load_weights(out)
    assert before.curvature_threshold is None and after.curvature_threshold == 0.62
    assert after.extra["epoch"] == 3 and after.model.spec == before.model.spec
    for name, tensor in before.model.state_dict().items():
        assert torch.equal(tensor, after.model.state_dict()[name]), name


def test_no_gt_or_no_usable_threshold_is_one_error(setup, capsys) -> None:
    root, weights, figures = setup
    argv = [str(weights), "--dataset", "dimo", "--data-root", str(root), "--split", "real"]
    assert calibrate_curvature.main(argv) == 2  # no figures: the split has no GT
    assert "has no ground truth" in capsys.readouterr().err
    figures.update(curvature_f1=0.1, curvature_best_f1=0.2, curvature_best_threshold=0.0)
    with pytest.raises(ConfigError, match="no usable threshold"):
        calibrate_curvature.calibrate(weights, "dimo", root, "real", weights)
    assert load_weights(weights).curvature_threshold is None  # nothing written


def test_a_threshold_for_one_split_leaves_the_general_one(setup, tmp_path, capsys) -> None:
    """``--for-split``: the threshold goes to the split's entry (others kept), the general one stays, and ``run`` on
    that split gets it (:meth:`NetWeights.curvature_threshold_for`)."""
    root, weights, figures = setup
    figures.update(curvature_f1=0.4, curvature_best_f1=0.6, curvature_best_threshold=0.62, curvature_ap=0.5)
    first = tmp_path / "general.pt"
    argv = [str(weights), "--dataset", "dimo", "--data-root", str(root), "--split", "real"]
    assert calibrate_curvature.main([*argv, "--out", str(first)]) == 0
    figures.update(curvature_best_threshold=0.51)
    out = tmp_path / "real.pt"
    assert calibrate_curvature.main([str(first), *argv[1:], "--out", str(out), "--for-split", "real"]) == 0
    assert "curvature_threshold for split real 0.510" in capsys.readouterr().out
    figures.update(curvature_best_threshold=0.7)
    assert calibrate_curvature.main([str(out), *argv[1:], "--for-split", "sim"]) == 0  # in place, another split
    after = load_weights(out)
    assert after.curvature_threshold == 0.62 and after.curvature_threshold_by_split == {"real": 0.51, "sim": 0.7}
    assert after.curvature_threshold_for("real") == (0.51, "real")
    assert after.curvature_threshold_for("test") == (0.62, None) and after.curvature_threshold_for(None) == (0.62, None)
    assert calibrate_curvature.main([*argv, "--for-split", " "]) == 2
    assert "--for-split: expected a split name" in capsys.readouterr().err


def test_the_card_beside_the_weights_gets_the_threshold(setup, tmp_path, capsys) -> None:
    """A card (``WEIGHTS.json`` naming the weights) states the threshold the weights now hold, general or per split,
    with where it was calibrated; its ``why`` and every other field stay. A JSON of something else is left alone; a
    damaged card is one error, and nothing is written."""
    import json

    root, weights, figures = setup
    figures.update(curvature_f1=0.4, curvature_best_f1=0.6, curvature_best_threshold=0.62, curvature_ap=0.5)
    card = {"weights": "w.pt", "epochs": 7, "curvature_threshold": {"value": 0.5, "why": "kept"},
            "curvature_threshold_by_split": {"sim": {"value": 0.3}}}  # fmt: skip
    (tmp_path / "w.json").write_text(json.dumps(card))
    argv = [str(weights), "--dataset", "dimo", "--data-root", str(root), "--split", "real"]
    assert calibrate_curvature.main(argv) == 0
    assert f"and its card {tmp_path / 'w.json'}" in capsys.readouterr().out
    after = json.loads((tmp_path / "w.json").read_text())
    entry = after["curvature_threshold"]
    assert entry["value"] == 0.62 == load_weights(weights).curvature_threshold and entry["why"] == "kept"
    assert entry["curvature_f1_at_t_b"] == 0.4 and entry["curvature_f1_at_value"] == 0.6
    assert "split real (4 validation views)" in entry["calibrated_on"] and "--split real" in entry["command"]
    assert after["epochs"] == 7 and after["curvature_threshold_by_split"] == {"sim": {"value": 0.3}}
    figures.update(curvature_best_threshold=0.51)
    assert calibrate_curvature.main([*argv, "--for-split", "real"]) == 0
    after = json.loads((tmp_path / "w.json").read_text())
    assert after["curvature_threshold"]["value"] == 0.62 and after["curvature_threshold_by_split"]["sim"] == {
        "value": 0.3
    }
    assert (
        after["curvature_threshold_by_split"]["real"]["value"]
        == 0.51
        == load_weights(weights).curvature_threshold_by_split["real"]
    )
    other = tmp_path / "o.pt"
    (tmp_path / "o.json").write_text('{"weights": "another.pt"}')
    assert calibrate_curvature.main([*argv, "--out", str(other)]) == 0
    assert (tmp_path / "o.json").read_text() == '{"weights": "another.pt"}'
    stale = tmp_path / "s.pt"  # --out onto weights with a card of their own: it would describe another network
    stale.write_bytes(b"old weights")
    (tmp_path / "s.json").write_text('{"weights": "s.pt", "network": {"name": "old"}}')
    assert calibrate_curvature.main([*argv, "--out", str(stale)]) == 2
    assert "s.json" in capsys.readouterr().err and stale.read_bytes() == b"old weights"
    (tmp_path / "w.json").write_text('{"weights": "w.pt", "curvature_threshold_by_split": [0.5]}')
    assert calibrate_curvature.main(argv) == 2
    assert "curvature_threshold_by_split" in capsys.readouterr().err
    (tmp_path / "w.json").write_text("{truncated")
    before = weights.read_bytes()
    figures.update(curvature_best_threshold=0.7)
    assert calibrate_curvature.main(argv) == 2
    err = capsys.readouterr().err
    assert "w.json" in err and "not readable JSON" in err and weights.read_bytes() == before
