"""The shipped DIMO weights load and give their card's figures on the card's fixed subset (regenerated here)."""

from __future__ import annotations

import json

import pytest

from bop_cender.data.registry import DatasetRequest, open_dataset
from bop_cender.meshes import MeshCache
from bop_cender.net.heatmap_eval import evaluate_heatmaps
from bop_cender.net.predictor import NetPredictor
from bop_cender.net.weights import load_weights, shipped_weights_path
from bop_cender.synth.generate import generate
from bop_cender.synth.write_dimo import DimoSpec


def test_shipped_dimo_weights_give_the_figures_of_their_card(tmp_path) -> None:
    path = shipped_weights_path("dimo")
    card = json.loads(path.with_suffix(".json").read_text())
    subset = card["subset"]  # a fixed, small set that this test regenerates: one synthetic scene
    spec = DimoSpec(n_scenes=subset["scenes"], variants=tuple(subset["variants"]), seed=subset["seed"],
                    write_real=False, contact_sheets=False)  # fmt: skip
    generate("dimo", tmp_path / "dimo", spec, progress=False)
    dataset = open_dataset(DatasetRequest("dimo", tmp_path / "dimo", subset["split"]))
    weights = load_weights(path, dataset="dimo")
    assert weights.model.spec.as_dict() == card["network"] and path.stat().st_size <= 20e6
    report = evaluate_heatmaps(
        dataset, NetPredictor(weights), weights.targets, MeshCache(dataset.models), str(path), progress=False
    )
    assert report.views == subset["views"]
    for name in ("center_f1", "center_precision", "center_recall", "curvature_ap", "curvature_f1"):
        assert report.metrics[name] == pytest.approx(subset["metrics"][name], abs=0.03), name
