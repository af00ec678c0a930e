"""Weights files: a round trip rebuilds the same network; every bad file is one clear error; the predictor's maps."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).parents[1]))
import method_data  # noqa: E402

from bop_cender.data.dimo import open_dimo  # noqa: E402
from bop_cender.errors import ConfigError  # noqa: E402
from bop_cender.net.predictor import NetPredictor, predict_probabilities, scene_images  # noqa: E402
from bop_cender.net.targets import TargetConfig  # noqa: E402
from bop_cender.net.unet import UNet, UNetSpec, center_probabilities  # noqa: E402
from bop_cender.net.weights import load_weights, save_weights, shipped_weights_path, weights_payload  # noqa: E402
from bop_cender.runner import RunRequest, net_predictor  # noqa: E402


def _save(path: Path, spec: UNetSpec, dataset: str = "dimo", ids=None, **extra) -> UNet:
    torch.manual_seed(0)
    model = UNet(spec).eval()
    save_weights(path, weights_payload(model, dataset, ids, TargetConfig.for_dataset(dataset), **extra))
    return model


def test_a_round_trip_rebuilds_the_same_network(tmp_path) -> None:
    model = _save(tmp_path / "w.pt", UNetSpec.tless_lean(center_channels=3, width=0.5), "tless", (1, 2, 5), epoch=7)
    loaded = load_weights(tmp_path / "w.pt", dataset="tless")
    assert loaded.model.spec == model.spec and loaded.channel_obj_ids == (1, 2, 5) and loaded.extra["epoch"] == 7
    assert loaded.targets == TargetConfig.for_dataset("tless")
    x = torch.rand(1, 3, 30, 33)
    with torch.no_grad():
        for a, b in zip(model(x), loaded.model(x), strict=True):
            assert torch.equal(a, b)
    assert load_weights(tmp_path / "w.pt", dataset="lmo").dataset == "tless"  # any BOP dataset takes tless weights


def test_bad_weights_files_are_one_clear_error(tmp_path) -> None:
    good = tmp_path / "good.pt"
    _save(good, UNetSpec.dimo_lean(width=0.5))
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(good.read_bytes()[:1000])
    foreign = tmp_path / "foreign.pt"
    torch.save({"state_dict": {}}, foreign)
    text = tmp_path / "text.pt"
    text.write_text("not weights")
    other_arch = tmp_path / "arch.pt"
    payload = torch.load(good, weights_only=True)
    payload["spec"] = UNetSpec.dimo_lean(width=1.0).as_dict()  # the state dict is of width 0.5
    torch.save(payload, other_arch)
    cases = [
        (tmp_path / "missing.pt", "not found"),
        (tmp_path, "is a directory"),
        (truncated, "not a readable weights file"),
        (text, r"not a readable weights file: not a torch file \(neither torch.save's zip archive nor a pickle\)"),
        (foreign, "not a bop-cender network weights file"),
        (other_arch, "do not fit their network spec"),
    ]
    for path, message in cases:
        with pytest.raises(ConfigError, match=message) as info:
            load_weights(path)
        assert str(path) in info.value.format() and "\n" not in info.value.format()
    with pytest.raises(ConfigError, match="trained for 'dimo' data; dataset 'tless'"):
        load_weights(good, dataset="tless")


def _edited(tmp_path: Path, good: Path, name: str, edit) -> Path:
    payload = torch.load(good, weights_only=True)
    edit(payload)
    path = tmp_path / name
    torch.save(payload, path)
    return path


def test_malformed_weights_contents_are_one_clear_error_naming_the_field(tmp_path) -> None:
    """What loads as a dict but cannot be used: non-finite weights (a diverged training run), target settings of
    the wrong type or range, channel ids that disagree with the network, an unknown dataset kind."""
    good = tmp_path / "good.pt"
    _save(good, UNetSpec.dimo_lean(width=0.5))
    tless = tmp_path / "tless.pt"
    _save(tless, UNetSpec.tless_lean(center_channels=3, width=0.5), "tless", (1, 2, 5))

    def nan_weights(p):
        next(v for v in p["state_dict"].values() if torch.is_floating_point(v))[0].fill_(float("nan"))

    def inf_bias(p):
        next(v for k, v in p["state_dict"].items() if k.endswith("bias"))[0] = float("inf")

    cases = [
        (good, "nan.pt", nan_weights, r"state_dict: non-finite values \(NaN or inf\) in e1\.body\.0\.weight"),
        (good, "inf.pt", inf_bias, r"state_dict: non-finite values"),
        (good, "s_e.pt", lambda p: p["targets"].update(s_e="x"), r"targets\.s_e: expected a number > 0, got 'x'"),
        (good, "visib.pt", lambda p: p["targets"].update(min_visib_fract=2.0), r"targets\.min_visib_fract"),
        (good, "flag.pt", lambda p: p["targets"].update(per_object_channels="no"), r"targets\.per_object_channels"),
        (good, "ids.pt", lambda p: p.update(channel_obj_ids=[1, 2]), r"channel_obj_ids: dimo weights have one shared"),
        (tless, "few.pt", lambda p: p.update(channel_obj_ids=[1, 2]), r"one object id per center channel \(3\), got 2"),
        (tless, "none.pt", lambda p: p.update(channel_obj_ids=None), r"channel \(3\), got none"),
        (tless, "dup.pt", lambda p: p.update(channel_obj_ids=[1, 1, 5]), r"distinct positive object ids"),
        (tless, "str.pt", lambda p: p.update(channel_obj_ids=["a", 2, 5]), r"channel_obj_ids: expected a list of obj"),
        (tless, "float.pt", lambda p: p.update(channel_obj_ids=[1.5, 2, 5]), r"channel_obj_ids: expected a list of"),
        (tless, "text.pt", lambda p: p.update(channel_obj_ids="125"), r"channel_obj_ids: expected a list of object"),
        (good, "kind.pt", lambda p: p.update(dataset="foo"), r"dataset: expected one of dimo, tless, got 'foo'"),
        (good, "nospec.pt", lambda p: p.pop("spec"), r"missing key 'spec'"),
        (good, "votes.pt", lambda p: p["spec"].update(center_votes="false"), r"center_votes must be true or false"),
        (good, "vsig.pt", lambda p: p["spec"].update(vote_sigma_px=True), r"vote_sigma_px must be a number, got True"),
        (good, "tiny.pt", lambda p: p["spec"].update(vote_sigma_px=1e-30), r"vote sigma must be 0\.1 to 100 pixels"),
        (good, "huge.pt", lambda p: p["spec"].update(vote_sigma_px=1e7), r"vote sigma must be 0\.1 to 100 pixels"),
        (
            good,
            "chan.pt",
            lambda p: p["spec"].update(channels=["16", 24, 32]),
            r"channels must be an integer, got '16'",
        ),
        (good, "width.pt", lambda p: p["spec"].update(width="1"), r"width must be a number"),
    ]
    for source, name, edit, message in cases:
        path = _edited(tmp_path, source, name, edit)
        with pytest.raises(ConfigError, match="malformed weights file.*" + message) as info:
            load_weights(path)
        assert str(path) in info.value.format() and "\n" not in info.value.format()
    empty = tmp_path / "empty.pt"
    empty.write_bytes(b"")
    with pytest.raises(ConfigError, match=r"truncated, or not written by torch\.save \(EOFError\)$"):
        load_weights(empty)


def test_the_predictor_gives_probabilities_of_every_view(tmp_path) -> None:
    root = method_data.build(tmp_path / "dimo")
    dataset = open_dimo(root, "real")
    scene = dataset.loader(dataset.scene_keys[0])
    _save(tmp_path / "w.pt", UNetSpec.dimo_lean(width=0.5))
    predictor = NetPredictor(load_weights(tmp_path / "w.pt", dataset="dimo"))
    maps = predictor.predict(scene)
    V, H, W = len(scene.views), scene.views[0].height, scene.views[0].width
    assert maps.center.shape == (V, 1, H, W) and maps.curvature.shape == (V, H, W)
    assert float(maps.center.min()) >= 0 and float(maps.center.max()) <= 1 and maps.im_ids == tuple(scene.im_ids)
    assert predictor.last_seconds_per_view > 0
    request = RunRequest(dataset="dimo", data_root=str(root), split="real", out=tmp_path / "x_dimo-real.csv",
                         heatmaps="net", weights=str(tmp_path / "w.pt"))  # fmt: skip
    assert isinstance(net_predictor(request, dataset), NetPredictor)
    _save(tmp_path / "t.pt", UNetSpec.tless_lean(center_channels=1, width=0.5), "tless", (3,))
    with pytest.raises(ConfigError, match="trained for 'tless'"):
        net_predictor(RunRequest(**{**request.__dict__, "weights": str(tmp_path / "t.pt")}), dataset)


def test_restricting_a_factored_networks_classes_drops_the_absent_ones_before_the_softmax() -> None:
    """The kept classes share sigmoid(center) in the proportions of their own softmax, whatever the absent
    classes' logits (even 60 ahead: renormalising probabilities would lose the present ones to underflow); a
    sample whose mask is all False keeps every class; a (B, C) mask restricts each sample on its own."""
    torch.manual_seed(4)
    raw = torch.randn(2, 1 + 4, 5, 6)
    raw[:, 2] += 60.0  # class 1 (absent) far ahead
    present = torch.tensor([True, False, True, False])
    out = center_probabilities(raw, True, present)
    o = torch.sigmoid(raw[:, :1])
    kept = torch.softmax(raw[:, [1, 3]], dim=1)
    assert torch.allclose(out[:, [0, 2]], o * kept, atol=1e-6) and float(out[:, [1, 3]].abs().max()) == 0.0
    assert torch.allclose(out.sum(1, keepdim=True), o, atol=1e-6)
    per_sample = center_probabilities(raw, True, torch.stack([present, torch.zeros(4, dtype=torch.bool)]))
    assert torch.allclose(per_sample[0], out[0]) and torch.allclose(per_sample[1], center_probabilities(raw, True)[1])
    assert torch.equal(center_probabilities(raw[:, :4], False, present), torch.sigmoid(raw[:, :4]))  # ignored
    objectness = torch.rand(2, 1, 5, 6)  # a vote map in place of sigmoid(center)
    voted = center_probabilities(raw, True, present, objectness)
    assert torch.allclose(voted[:, [0, 2]], objectness * kept, atol=1e-6) and float(voted[:, [1, 3]].abs().max()) == 0
    with pytest.raises(ValueError, match="class_mask must be"):
        center_probabilities(raw, True, torch.ones(3, dtype=torch.bool))


def test_the_known_class_mask_marks_the_channels_of_the_known_ids() -> None:
    from bop_cender.net.predictor import known_class_mask

    assert known_class_mask((3, 4, 7), {4, 100}).tolist() == [False, True, False]
    assert known_class_mask((3, 4, 7), frozenset()).dtype == torch.bool


def test_the_predictor_restricts_a_factored_network_to_the_scene_ids(tmp_path) -> None:
    root = method_data.build(tmp_path / "dimo")
    scene = open_dimo(root, "real").loader(open_dimo(root, "real").scene_keys[0])
    ids = (3, 4, 7)  # the scene holds parts 3 and 4 (and the carrier 100), not 7
    model = _save(tmp_path / "f.pt", UNetSpec.tless_factored(center_channels=3, width=0.25), "tless", ids)
    with torch.no_grad():
        model.center_head.body[-1].bias.copy_(torch.tensor([2.0, 0.0, 0.0, 3.0]))  # channel 7 favoured
    save_weights(tmp_path / "f.pt", weights_payload(model, "tless", ids, TargetConfig.for_dataset("tless")))
    weights = load_weights(tmp_path / "f.pt", dataset="tless")
    maps = NetPredictor(weights).predict(scene)
    free_maps = NetPredictor(weights, known_object_ids=False).predict(scene)
    restricted, free = maps.center, free_maps.center
    assert float(free[:, 2].mean()) > float(free[:, :2].mean(1).mean())  # unrestricted: 7 takes the most
    # The maps hold the scene's ids' channels only (7's would be exactly 0), each as the full restricted maps have it
    assert maps.channel_obj_ids == (3, 4) and free_maps.channel_obj_ids == ids and restricted.shape[1] == 2
    assert maps.exclusive_channels  # a factored head's channels split one probability: stage 2 sums them
    dense = predict_probabilities(weights.model, scene_images(scene), class_mask=torch.tensor([True, True, False]))[0]
    assert torch.equal(restricted, dense[:, :2]) and float(dense[:, 2].abs().max()) == 0.0
    assert torch.allclose(restricted.sum(1), free.sum(1), atol=1e-5)  # the centre probability is kept
    assert torch.equal(maps.curvature, free_maps.curvature)
    # A scene whose GT holds none of the network's ids: every channel, as without GT
    stranger = NetPredictor(weights).predict(replace(scene, gt=tuple(g for g in scene.gt if g.obj_id not in ids)))
    assert stranger.channel_obj_ids == ids and torch.equal(stranger.center, free)


def test_compact_probabilities_are_the_kept_channels_of_the_dense_ones() -> None:
    """compact: the True classes' channels alone, bit for bit those of the dense maps (votes too); a factored head
    and a (C,) mask are required; a mask with no True class keeps every class."""
    torch.manual_seed(6)
    raw = torch.randn(3, 1 + 5, 7, 9)
    present = torch.tensor([False, True, False, True, True])
    objectness = torch.rand(3, 1, 7, 9)
    for obj in (None, objectness):
        dense = center_probabilities(raw, True, present, obj)
        assert torch.equal(center_probabilities(raw, True, present, obj, compact=True), dense[:, [1, 3, 4]])
    none = torch.zeros(5, dtype=torch.bool)
    assert torch.equal(center_probabilities(raw, True, none, compact=True), center_probabilities(raw, True))
    for args in ((raw, False, present), (raw, True, None), (raw, True, present.expand(3, -1))):
        with pytest.raises(ValueError, match="compact needs"):
            center_probabilities(*args, compact=True)


def test_test_flips_average_the_passes_flipped_back() -> None:
    """flips 2: the center maps are the mean of the image's and its left-right flip's probabilities (flipped back);
    4 adds the up-down ones; the curvature map is the image's alone. A mirrored image then gives the mirrored
    center maps exactly (the passes are the same set)."""
    torch.manual_seed(5)
    model = UNet(UNetSpec.dimo_lean(width=0.5)).eval()
    with torch.no_grad():  # random BatchNorm statistics: a network that is far from flip-equivariant
        for m in model.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.uniform_(-0.2, 0.2)
        for head in (model.center_head, model.curvature_head):
            head.body[-1].weight.normal_(0.0, 20.0)
            head.body[-1].bias.zero_()
    image = torch.rand(3, 3, 32, 40)
    with torch.no_grad():
        c0, k0 = (torch.sigmoid(x) for x in model(image))
        c1, k1 = (torch.sigmoid(x) for x in model(image.flip(-1)))
    center, curvature = predict_probabilities(model, image, batch_size=2, flips=2)
    assert torch.allclose(center, (c0 + c1.flip(-1)) / 2, atol=1e-6)
    assert torch.allclose(curvature, k0, atol=1e-6)
    assert not torch.allclose(center, c0, atol=1e-3)  # the flip changed something
    for flips, dims in ((2, (-1,)), (4, (-1,)), (4, (-2,))):
        c, k = predict_probabilities(model, image, flips=flips)
        cm, _ = predict_probabilities(model, image.flip(dims), flips=flips)
        assert torch.allclose(cm, c.flip(dims), atol=1e-5)
    with pytest.raises(ValueError, match="expected one of"):
        predict_probabilities(model, image, flips=3)


def test_the_run_config_has_no_test_flips_and_says_where_their_figures_are() -> None:
    """Test-time flips lost end to end with both shipped networks and were off: run's config dropped them (the
    predictor keeps them for ``heatmaps --test-flips``)."""
    from bop_cender.method import CenDerNetConfig

    with pytest.raises(ConfigError, match="test_flips was removed: .* figures: results/accuracy/README.md"):
        CenDerNetConfig.for_dataset("dimo").with_settings(["test_flips=4"])
    assert not hasattr(CenDerNetConfig(), "test_flips")


def test_shipped_weights_are_found_or_named_missing() -> None:
    for kind in ("dimo", "tless"):
        try:
            path = shipped_weights_path(kind)
        except ConfigError as e:
            assert "no shipped network weights" in str(e)
            continue
        assert path.is_file() and np.isfinite(path.stat().st_size)


def test_mixed_sources_take_each_head_from_its_own_predictor(tmp_path) -> None:
    """``oracle-centers``: the oracle's centres with the network's curvature; ``oracle-curvature``: the reverse."""
    from bop_cender.net.mixed import MixedPredictor
    from bop_cender.runner import build_method

    root = method_data.build(tmp_path / "dimo")
    dataset = open_dimo(root, "real")
    scene = dataset.loader(dataset.scene_keys[0])
    _save(tmp_path / "w.pt", UNetSpec.dimo_lean(width=0.5))
    request = RunRequest(dataset="dimo", data_root=str(root), split="real", out=tmp_path / "x_dimo-real.csv",
                         heatmaps="net", weights=str(tmp_path / "w.pt"))  # fmt: skip
    maps = {
        source: build_method(replace(request, heatmaps=source), dataset).predictor.predict(scene)
        for source in ("net", "oracle", "oracle-centers", "oracle-curvature")
    }
    assert not torch.equal(maps["net"].center, maps["oracle"].center)
    # two oracle renders may differ in the last bits (threaded scatter order): close, the network's are far
    assert torch.allclose(maps["oracle-centers"].center, maps["oracle"].center, atol=1e-5)
    assert torch.equal(maps["oracle-centers"].curvature, maps["net"].curvature)
    assert torch.equal(maps["oracle-curvature"].center, maps["net"].center)
    assert torch.allclose(maps["oracle-curvature"].curvature, maps["oracle"].curvature, atol=1e-5)
    mixed = build_method(replace(request, heatmaps="oracle-curvature"), dataset).predictor
    assert isinstance(mixed, MixedPredictor) and mixed.last_seconds_per_view is None
    mixed.predict(scene)
    assert mixed.last_seconds_per_view > 0 and mixed.name == "net-centers+oracle-curvature"
    with pytest.raises(ConfigError, match="unknown heatmap source 'half'"):
        from bop_cender.runner import run

        run(replace(request, heatmaps="half"), dataset)


def test_a_calibrated_curvature_threshold_is_read_checked_and_passed_to_the_heatmaps(tmp_path) -> None:
    """The weights' ``curvature_threshold`` reaches the predictor's heatmaps, ``poses.network.t_b`` overrides it,
    and a value outside (0, 1) is one error naming the file."""
    from bop_cender.method import CenDerNetConfig, network_curvature_choice

    root = method_data.build(tmp_path / "dimo")
    dataset = open_dimo(root, "real")
    scene = dataset.loader(dataset.scene_keys[0])
    _save(tmp_path / "plain.pt", UNetSpec.dimo_lean(width=0.5))
    _save(tmp_path / "cal.pt", UNetSpec.dimo_lean(width=0.5), curvature_threshold=0.55)
    assert load_weights(tmp_path / "plain.pt").curvature_threshold is None
    calibrated = load_weights(tmp_path / "cal.pt")
    assert calibrated.curvature_threshold == 0.55 and "curvature_threshold" not in calibrated.extra
    request = RunRequest(dataset="dimo", data_root=str(root), split="real", out=tmp_path / "x_dimo-real.csv",
                         heatmaps="net", weights=str(tmp_path / "cal.pt"))  # fmt: skip
    assert net_predictor(request, dataset).predict(scene).curvature_threshold == 0.55
    assert NetPredictor(calibrated).predict(scene).curvature_threshold == 0.55  # the API's default too
    assert NetPredictor(calibrated).predict(scene).centers_from_network  # stage 3 searches its centres wider
    with pytest.raises(ValueError, match="curvature_threshold must be in"):
        replace(NetPredictor(calibrated).predict(scene), curvature_threshold=float("nan"))
    given = CenDerNetConfig.for_dataset("dimo").with_settings(["poses.network.t_b=0.4"])
    assert net_predictor(replace(request, config=given), dataset).predict(scene).curvature_threshold == 0.4
    assert (
        network_curvature_choice(CenDerNetConfig(), load_weights(tmp_path / "plain.pt").curvature_threshold)[0] is None
    )
    from bop_cender.runner import build_method

    # the threshold goes with the curvature: the network's in oracle-centers, the oracle's (None: t_b) in the reverse
    for source, expected in (("oracle-centers", 0.55), ("oracle-curvature", None), ("oracle", None)):
        maps = build_method(replace(request, heatmaps=source), dataset).predictor.predict(scene)
        assert maps.curvature_threshold == expected, source
        assert maps.to("cpu").curvature_threshold == expected
    for bad in (1.5, 0.0, float("nan"), "0.5"):
        _save(tmp_path / "bad.pt", UNetSpec.dimo_lean(width=0.5), curvature_threshold=bad)
        with pytest.raises(ConfigError, match="curvature_threshold: expected a number in") as info:
            load_weights(tmp_path / "bad.pt")
        assert str(tmp_path / "bad.pt") in info.value.format()
    for bad in ({"real": 1.5}, {"": 0.5}, {"real": "0.5"}, [0.5], {3: 0.5}):
        _save(tmp_path / "bad.pt", UNetSpec.dimo_lean(width=0.5), curvature_threshold_by_split=bad)
        with pytest.raises(ConfigError, match="curvature_threshold_by_split: expected split names") as info:
            load_weights(tmp_path / "bad.pt")
        assert str(tmp_path / "bad.pt") in info.value.format()
    # a threshold calibrated on the run's split wins over the general one, for that split alone
    _save(tmp_path / "split.pt", UNetSpec.dimo_lean(width=0.5), curvature_threshold=0.55,
          curvature_threshold_by_split={"real": 0.45})  # fmt: skip
    split = replace(request, weights=str(tmp_path / "split.pt"))
    assert net_predictor(split, dataset).predict(scene).curvature_threshold == 0.45
    assert "curvature_threshold_by_split" not in load_weights(tmp_path / "split.pt").extra
    assert net_predictor(replace(split, split="sim"), dataset).predict(scene).curvature_threshold == 0.55


def test_every_layout_finds_the_shipped_weights_of_its_kind() -> None:
    from bop_cender.net.weights import shipped_weights_path, weights_kind

    assert [weights_kind(d) for d in ("dimo", "tless", "bop", "ipd")] == ["dimo", "tless", "tless", "tless"]
    assert shipped_weights_path("bop") == shipped_weights_path("tless") != shipped_weights_path("dimo")
