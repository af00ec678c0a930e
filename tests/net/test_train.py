"""Training stage 1: the loss falls, a resumed run equals an uninterrupted one, targets are cached, runs are guarded."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).parents[1]))
import method_data  # noqa: E402

from bop_cender.cli import main  # noqa: E402
from bop_cender.data.bop_io import write_image  # noqa: E402
from bop_cender.data.registry import DatasetRequest, open_dataset  # noqa: E402
from bop_cender.errors import ConfigError  # noqa: E402
from bop_cender.meshes import MeshCache  # noqa: E402
from bop_cender.net import samples as samples_module  # noqa: E402
from bop_cender.net.targets import TargetConfig, scene_targets  # noqa: E402
from bop_cender.net.train import (  # noqa: E402
    CHECKPOINT,
    METRICS,
    WEIGHTS,
    TrainConfig,
    center_class_loss,
    center_focal_loss,
    center_loss,
    random_crop,
    train,
)
from bop_cender.net.unet import UNetSpec  # noqa: E402
from bop_cender.net.weights import load_weights  # noqa: E402


@pytest.fixture(scope="module")
def tiny_root(tmp_path_factory) -> Path:
    """Two DIMO-layout scenes of two L-parts, 4 views each at 160x128, whose colour images show the parts (the
    builder's are black): grey curvature plus a faint disk at each centre, so that there is something to learn."""
    root = method_data.build(tmp_path_factory.mktemp("dimo_tiny"), n_scenes=2)
    dataset = open_dataset(DatasetRequest("dimo", root, "real"))
    meshes = MeshCache(dataset.models)
    for key in dataset.scene_keys:
        scene = dataset.loader(key)
        maps = scene_targets(scene, dataset.models, meshes, TargetConfig.for_dataset("dimo"))
        shown = (maps.curvature + 0.4 * (maps.center[:, 0] > 0.5)).clamp(0, 1)
        for view, grey in zip(scene.views, shown, strict=True):
            write_image(view.rgb_path, (grey[..., None].repeat(1, 1, 3) * 255).round().to(torch.uint8).numpy())
    return root


def _config(root: Path, **kw) -> TrainConfig:
    base = dict(dataset="dimo", data_root=str(root), split="real", val_split="real", epochs=2, batch_size=4,
                variant="dimo-lean", width=0.5, seed=3, lr=3e-3)  # fmt: skip
    return TrainConfig(**{**base, **kw})


def test_a_short_run_lowers_the_loss_and_writes_its_files(tiny_root, tmp_path) -> None:
    torch.set_num_threads(2)
    config = _config(tiny_root, epochs=5, batch_size=2, lr=1e-2, augment=False)
    summary = train(config, tmp_path / "run", cache_dir=tmp_path / "cache", progress=False)
    losses = [r.train_loss for r in summary.history]
    assert len(losses) == 5 and losses[-1] < 0.7 * losses[0], losses
    for name in (CHECKPOINT, WEIGHTS, METRICS, "config.json"):
        assert (tmp_path / "run" / name).is_file()
    rows = (tmp_path / "run" / METRICS).read_text().splitlines()
    assert len(rows) == 6 and "val_center_f1" in rows[0] and "val_curvature_ap" in rows[0]
    weights = load_weights(tmp_path / "run" / WEIGHTS, dataset="dimo")
    assert weights.extra["epoch"] == 5 and weights.channel_obj_ids is None
    assert {"center_f1", "curvature_ap", "center_loss"} <= set(summary.history[-1].val)
    # the weights carry the last validation's calibrated curvature threshold (where stage 3 binarises their maps)
    best = summary.history[-1].val["curvature_best_threshold"]
    assert 0.0 < best < 1.0 and weights.curvature_threshold == pytest.approx(best)
    assert summary.history[-1].val["curvature_best_f1"] >= summary.history[-1].val["curvature_f1"]


def test_a_resumed_run_equals_an_uninterrupted_one(tiny_root, tmp_path) -> None:
    cache = tmp_path / "cache"
    whole = train(_config(tiny_root, epochs=2), tmp_path / "whole", cache_dir=cache, progress=False)
    train(_config(tiny_root, epochs=1), tmp_path / "split", cache_dir=cache, progress=False)
    resumed = train(_config(tiny_root, epochs=2), tmp_path / "split", resume=True, cache_dir=cache, progress=False)
    assert resumed.resumed_from == 1
    a = load_weights(tmp_path / "whole" / WEIGHTS).model.state_dict()
    b = load_weights(tmp_path / "split" / WEIGHTS).model.state_dict()
    for key in a:
        assert torch.equal(a[key], b[key]), key
    assert [r.train_loss for r in whole.history] == [r.train_loss for r in resumed.history]


def test_targets_are_rendered_once_then_read_from_the_cache(tiny_root, tmp_path, monkeypatch) -> None:
    cache = tmp_path / "cache"
    train(_config(tiny_root, epochs=1, val_split=None), tmp_path / "a", cache_dir=cache, progress=False)
    files = sorted((cache / "targets").rglob("*.npz"))
    assert len(files) == 2

    def no_render(*args, **kwargs):
        raise AssertionError("targets rendered again")

    monkeypatch.setattr(samples_module, "scene_targets_with_votes", no_render)
    train(_config(tiny_root, epochs=1, val_split=None), tmp_path / "b", cache_dir=cache, progress=False)
    files[0].write_bytes(b"damaged")  # a damaged cache file is rendered again
    monkeypatch.undo()
    train(_config(tiny_root, epochs=1, val_split=None), tmp_path / "c", cache_dir=cache, progress=False)
    assert sorted((cache / "targets").rglob("*.npz")) == files


def _damaged_caches(path: Path):
    """Ways a cached targets file goes bad (name, damage), each applied to the good file's arrays or bytes."""
    import io
    import zipfile

    import numpy as np

    good = path.read_bytes()
    with np.load(io.BytesIO(good)) as data:
        arrays = {k: data[k] for k in data.files}

    def saved(**changes):
        def write(p: Path) -> None:
            with open(p, "wb") as f:
                np.savez_compressed(f, **{**arrays, **changes})

        return write

    table = arrays["vote_table"]
    nan_table = table.copy()
    nan_table[0, 1] = np.nan
    far_view = table.copy()
    far_view[0, 0] = 99
    big_ids = arrays["vote_ids"].copy()
    big_ids[0, 0, 0] = 200
    with zipfile.ZipFile(io.BytesIO(good)) as z:  # an archive whose compressed bytes are flipped
        member = z.infolist()[0]
        offset = member.header_offset + 30 + len(member.filename) + len(member.extra) + 40
    flipped = bytearray(good)
    flipped[offset : offset + 64] = bytes(b ^ 0xFF for b in flipped[offset : offset + 64])
    return [
        ("truncated", lambda p: p.write_bytes(good[: len(good) // 2])),
        ("empty", lambda p: p.write_bytes(b"")),
        ("flipped bytes", lambda p: p.write_bytes(bytes(flipped))),
        ("a bare array", lambda p: np.save(open(p, "wb"), arrays["center"])),
        ("fewer views of vote ids", saved(vote_ids=arrays["vote_ids"][:1])),
        ("another height", saved(center=arrays["center"][:, :, :-1])),
        ("float maps", saved(center=arrays["center"].astype(np.float64))),
        ("an id beyond its table", saved(vote_ids=big_ids)),
        ("a table of 3 columns", saved(vote_table=table[:, :3])),
        ("NaN in the table", saved(vote_table=nan_table)),
        ("a view beyond the scene", saved(vote_table=far_view)),
    ]


def test_a_damaged_targets_cache_file_is_rendered_again_whatever_the_damage(tiny_root, tmp_path) -> None:
    import numpy as np

    from bop_cender.net.samples import _read_cached_targets, _scene_targets_cached

    dataset = open_dataset(DatasetRequest("dimo", tiny_root, "real"))
    meshes = MeshCache(dataset.models)
    scene = dataset.loader(dataset.scene_keys[0])
    config = TargetConfig.for_dataset("dimo")
    cache = tmp_path / "cache"
    center, curvature, votes = _scene_targets_cached(scene, dataset, config, meshes, None, cache)
    (path,) = sorted((cache / "targets").rglob("*.npz"))
    for name, damage in _damaged_caches(path):
        damage(path)
        c, k, v = _scene_targets_cached(scene, dataset, config, meshes, None, cache)
        assert np.array_equal(c, center) and np.array_equal(k, curvature), name
        assert np.array_equal(v.ids, votes.ids) and all(
            np.array_equal(a, b) for a, b in zip(v.tables, votes.tables, strict=True)
        ), name
        replaced = _read_cached_targets(path, scene, 1)  # the file is replaced by a good one
        assert replaced is not None and np.array_equal(replaced[0], center), name


def test_runs_are_guarded(tiny_root, tmp_path) -> None:
    train(_config(tiny_root, epochs=1, val_split=None), tmp_path / "run", progress=False)
    with pytest.raises(ConfigError, match="--resume"):
        train(_config(tiny_root, epochs=1, val_split=None), tmp_path / "run", progress=False)
    with pytest.raises(ConfigError, match="other settings.*lr"):
        train(_config(tiny_root, epochs=2, val_split=None, lr=1e-4), tmp_path / "run", resume=True, progress=False)
    (tmp_path / "file").write_text("x")
    with pytest.raises(ConfigError, match="not a directory"):
        train(_config(tiny_root), tmp_path / "file", progress=False)
    bad_settings = (dict(epochs=0), dict(batch_size=0), dict(lr=float("nan")), dict(width=-1.0), dict(crop=(0, 4)),
                    dict(center_pos_weight=-1.0), dict(center_pos_weight=float("inf")), dict(center_loss="l2"),
                    dict(center_loss="focal", center_pos_weight=10.0), dict(center_loss_weight=0.0),
                    dict(center_loss_weight=float("nan")))  # fmt: skip
    for bad in bad_settings:
        with pytest.raises(ConfigError):
            _config(tiny_root, **bad)
    with pytest.raises(ConfigError, match="--val-data-root: validation data needs --val-split"):
        _config(tiny_root, val_split=None, val_data_root=str(tiny_root))
    with pytest.raises(ConfigError, match=r"--crop: 200x100 is larger than the training images \(128x160\)"):
        train(_config(tiny_root, epochs=1, val_split=None, crop=(200, 100)), tmp_path / "crop", progress=False)
    with pytest.raises(ConfigError, match="--val-split"):  # the validation split's own flag, not --split
        train(_config(tiny_root, epochs=1, val_split="nosuch"), tmp_path / "val", progress=False)
    said = []
    train(_config(tiny_root, epochs=1, val_split=None), tmp_path / "fresh", resume=True, progress=False,
          announce=said.append)  # fmt: skip
    assert any("holds no checkpoint yet; starting a new run" in line for line in said)


@pytest.mark.parametrize(
    ("damage", "field"),
    [
        (lambda p: p["config"].update(old_option=1), "config"),  # another version's settings
        (lambda p: p["config"].update(crop="64x64"), "config"),
        (lambda p: p.pop("epoch"), "epoch"),
        (lambda p: p.update(epoch="x"), "epoch"),
        (lambda p: p.update(history=[{"foo": 1}]), "history"),
        (lambda p: p.update(history=[3]), "history"),
        (lambda p: p.update(optimiser={"state": {}, "param_groups": []}), "optimiser"),
    ],
)
def test_resuming_from_a_checkpoint_of_other_contents_is_one_error_naming_the_field(tiny_root, tmp_path, damage, field):
    """A checkpoint of another version (or edited) ended in a traceback from deep in the restore."""
    run = tmp_path / "run"
    train(_config(tiny_root, epochs=1, val_split=None), run, progress=False)
    path = run / "checkpoint.pt"
    payload = torch.load(path, weights_only=True)
    damage(payload)
    torch.save(payload, path)
    with pytest.raises(ConfigError) as caught:
        train(_config(tiny_root, epochs=2, val_split=None), run, resume=True, progress=False)
    assert str(caught.value.file) == str(path) and caught.value.field == field, caught.value.format()


def test_a_diverged_run_stops_with_one_error_and_keeps_the_last_good_checkpoint(tiny_root, tmp_path, monkeypatch):
    """A non-finite loss ends the run (never NaN weights written with exit 0): the error names the epoch, the batch
    and --lr, and the previous epoch's checkpoint, weights and metrics are what is left."""
    from bop_cender.net import train as train_module

    real_loss, calls = train_module._center_loss, []

    def nan_in_epoch_two(*args, **kwargs):
        calls.append(1)
        loss = real_loss(*args, **kwargs)
        return loss * float("nan") if len(calls) == 5 else loss  # 4 batches of 2 views per epoch

    monkeypatch.setattr(train_module, "_center_loss", nan_in_epoch_two)
    run = tmp_path / "run"
    with pytest.raises(ConfigError, match=r"--lr: training diverged: the loss became nan at epoch 2, batch 1 of 4"):
        train(_config(tiny_root, epochs=3, batch_size=2, val_split=None), run, progress=False)
    assert load_weights(run / WEIGHTS).extra["epoch"] == 1 and load_weights(run / CHECKPOINT).extra["epoch"] == 1
    assert len((run / METRICS).read_text().splitlines()) == 2
    monkeypatch.undo()
    with pytest.raises(ConfigError, match=r"training diverged: the (loss|weights) became"):
        train(_config(tiny_root, epochs=1, batch_size=2, val_split=None, lr=1e30), tmp_path / "huge", progress=False)
    assert not (tmp_path / "huge").exists()  # nothing of a run that stopped before its first checkpoint


def test_a_run_stopped_in_its_first_epoch_leaves_out_as_it_was(tiny_root, tmp_path, monkeypatch) -> None:
    """Ctrl-C (or a crash) in epoch 1: no config.json, no half run in --out, a folder given empty stays empty."""
    from bop_cender.net import train as train_module

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(train_module, "_center_loss", interrupted)
    for run in (tmp_path / "new", tmp_path / "empty"):
        if run.name == "empty":
            run.mkdir()
        with pytest.raises(KeyboardInterrupt):
            train(_config(tiny_root, epochs=2, val_split=None), run, progress=False)
    assert not (tmp_path / "new").exists() and list((tmp_path / "empty").iterdir()) == []


def test_random_crops_cut_image_and_targets_alike() -> None:
    image = torch.arange(2 * 3 * 8 * 10, dtype=torch.float32).view(2, 3, 8, 10)
    center = image[:, :1].clone()
    curvature = image[:, 0].clone()
    gen = torch.Generator().manual_seed(0)
    a, b, c, _ = random_crop(image, center, curvature, (4, 5), gen)
    assert a.shape == (2, 3, 4, 5) and b.shape == (2, 1, 4, 5) and c.shape == (2, 4, 5)
    assert torch.equal(a[:, :1], b) and torch.equal(a[:, 0], c)
    whole = random_crop(image, center, curvature, (20, 20), gen)[0]
    assert torch.equal(whole, image)  # no crop larger than the image


def test_fine_tuning_starts_from_the_given_weights(tiny_root, tmp_path) -> None:
    train(_config(tiny_root, epochs=1, val_split=None), tmp_path / "first", progress=False)
    first = tmp_path / "first" / WEIGHTS
    tuned = train(
        _config(tiny_root, epochs=1, val_split=None, lr=1e-9, init_weights=str(first), augment=False),
        tmp_path / "tuned",
        progress=False,
    )
    assert tuned.epochs_done == 1
    a = load_weights(first).model.state_dict()
    b = load_weights(tmp_path / "tuned" / WEIGHTS).model.state_dict()
    for key in a:
        if "running" not in key and "num_batches" not in key:  # BatchNorm statistics move whatever the lr
            assert torch.allclose(a[key].float(), b[key].float(), atol=1e-5), key
    with pytest.raises(ConfigError, match="not this run's"):
        train(
            _config(tiny_root, epochs=1, val_split=None, width=1.0, init_weights=str(first)),
            tmp_path / "x",
            progress=False,
        )
    for missing in (tmp_path / "none.pt", tmp_path):  # errors of the file name the option that gave it
        with pytest.raises(ConfigError, match="--init-weights: "):
            train(
                _config(tiny_root, epochs=1, val_split=None, init_weights=str(missing)), tmp_path / "z", progress=False
            )
    # a lean network starts a context one (its new convolutions start as the identity), not the reverse
    context = train(
        _config(tiny_root, epochs=1, val_split=None, variant="dimo-context", init_weights=str(first)),
        tmp_path / "context",
        progress=False,
    )
    assert context.epochs_done == 1
    context_weights = tmp_path / "context" / WEIGHTS
    assert load_weights(context_weights).model.spec.context_dilations == (2, 4, 8)
    with pytest.raises(ConfigError, match="not this run's"):
        train(_config(tiny_root, epochs=1, val_split=None, init_weights=str(context_weights)), tmp_path / "y",
              progress=False)  # fmt: skip
    # a context network starts a refine one (full-resolution curvature refinement, also the identity at first)
    refined = train(
        _config(tiny_root, epochs=1, val_split=None, variant="dimo-refine", init_weights=str(context_weights)),
        tmp_path / "refine",
        progress=False,
    )
    assert refined.epochs_done == 1
    assert load_weights(tmp_path / "refine" / WEIGHTS).model.spec.refine_channels == 8
    # the refinement and the curvature head alone: every other weight and statistic stays, so do the centres
    only = ("refine", "curvature_head")
    alone = _config(tiny_root, epochs=1, val_split=None, variant="dimo-refine", init_weights=str(context_weights),
                    train_only=only)  # fmt: skip
    train(alone, tmp_path / "alone", progress=False)
    before = load_weights(context_weights).model
    after = load_weights(tmp_path / "alone" / WEIGHTS).model
    b, a = before.state_dict(), after.state_dict()
    assert all(torch.equal(b[k], a[k]) for k in b if not k.startswith(only)), [
        k for k in b if not torch.equal(b[k], a[k])
    ]
    assert any(not torch.equal(b[k], a[k]) for k in b if k.startswith("curvature_head"))
    assert any(not torch.equal(v, torch.zeros_like(v)) for k, v in a.items() if k.startswith("refine.out_weight"))
    image = torch.rand(1, 3, 128, 160)
    with torch.no_grad():
        assert torch.equal(before.eval()(image)[0], after.eval()(image)[0])
    # a context network starts a centres one; its branch and center head alone leave the curvature as it was
    centers_only = ("center_branch", "center_head")
    centers = _config(tiny_root, epochs=1, val_split=None, variant="dimo-centers", init_weights=str(context_weights),
                      train_only=centers_only)  # fmt: skip
    train(centers, tmp_path / "centers", progress=False)
    after = load_weights(tmp_path / "centers" / WEIGHTS).model
    assert after.spec.center_branch_channels == 48
    a = after.state_dict()
    assert all(torch.equal(b[k], a[k]) for k in b if not k.startswith(centers_only))
    assert any(not torch.equal(v, torch.zeros_like(v)) for k, v in a.items() if k.startswith("center_branch.out"))
    with torch.no_grad():
        (c0, k0), (c1, k1) = before.eval()(image), after.eval()(image)
    assert torch.equal(k0, k1) and not torch.equal(c0, c1)
    with pytest.raises(ConfigError, match="--train-only.*bogus: not a module of the dimo-refine network"):
        train(replace(alone, train_only=("refine", "bogus")), tmp_path / "bogus", progress=False)
    with pytest.raises(ConfigError, match="--train-only"):
        replace(alone, train_only=("refine", "refine"))


def test_the_center_pos_weight_weights_blob_pixels_only() -> None:
    """0 is the paper's plain BCE; w weights each pixel 1 + w * target, so background pixels count as before."""
    torch.manual_seed(0)
    logits = torch.randn(2, 3, 8, 9)
    target = torch.zeros(2, 3, 8, 9)
    target[0, 1, 2:5, 3:6] = torch.tensor([0.5, 1.0, 0.5]).view(3, 1)
    plain = torch.nn.functional.binary_cross_entropy_with_logits(logits, target)
    assert torch.equal(center_loss(logits, target, 0.0), plain)
    per_pixel = torch.nn.functional.binary_cross_entropy_with_logits(logits, target, reduction="none")
    expected = (per_pixel * (1 + 10.0 * target)).mean()
    assert torch.allclose(center_loss(logits, target, 10.0), expected)


def _blob(h: int, w: int, v: float, u: float, sigma: float) -> torch.Tensor:
    rows, cols = torch.meshgrid(torch.arange(h) + 0.5, torch.arange(w) + 0.5, indexing="ij")
    return torch.exp(-((rows - v) ** 2 + (cols - u) ** 2) / (2 * sigma**2))


def test_the_focal_loss_counts_each_blob_peak_once_and_forgives_near_misses() -> None:
    """CenterNet's loss: positives are the blobs' peak pixels (one per blob, even off-centre ones), the loss is
    normalised by their number, and a prediction one pixel off the peak costs less than one far away."""
    target = torch.maximum(_blob(32, 40, 10.3, 12.8, 3.0), _blob(32, 40, 22.6, 30.1, 2.0)).view(1, 1, 32, 40)
    peaks = (target >= 0.9) & (target >= torch.nn.functional.max_pool2d(target, 3, stride=1, padding=1))
    assert int(peaks.sum()) == 2 and bool(peaks[0, 0, 10, 12]) and bool(peaks[0, 0, 22, 30])

    def logits_with_peak_at(v: int, u: int) -> torch.Tensor:
        logits = torch.full_like(target, -8.0)
        logits[0, 0, 22, 30] = 4.0
        logits[0, 0, v, u] = 4.0
        return logits

    exact = center_focal_loss(logits_with_peak_at(10, 12), target)
    near = center_focal_loss(logits_with_peak_at(10, 13), target)
    far = center_focal_loss(logits_with_peak_at(25, 5), target)
    assert exact < near < far
    # hand-computed: the two peaks at p = sigmoid(4) cost (1 - p)^2 * -log p each; the background at
    # sigmoid(-8) costs next to nothing; the loss is their sum over the two blobs
    p = torch.sigmoid(torch.tensor(4.0))
    assert abs(float(exact) - float((1 - p) ** 2 * -torch.log(p))) < 1e-4
    # a batch of two images with the same blobs: the same normalised loss
    assert torch.allclose(center_focal_loss(logits_with_peak_at(10, 12).repeat(2, 1, 1, 1), target.repeat(2, 1, 1, 1)),
                          exact)  # fmt: skip
    # no blob at all: the loss is the background's alone and finite
    assert torch.isfinite(center_focal_loss(torch.zeros(1, 1, 8, 8), torch.zeros(1, 1, 8, 8)))


def test_a_focal_run_lowers_its_loss(tiny_root, tmp_path) -> None:
    torch.set_num_threads(2)
    config = _config(tiny_root, epochs=4, batch_size=2, lr=1e-2, augment=False, center_loss="focal",
                     center_loss_weight=0.1, val_split=None)  # fmt: skip
    summary = train(config, tmp_path / "run", cache_dir=tmp_path / "cache", progress=False)
    centers = [r.train_center_loss for r in summary.history]
    assert centers[-1] < 0.7 * centers[0], centers


def test_the_class_loss_classifies_blob_cores_by_their_strongest_channel() -> None:
    """Pixels where the strongest blob exceeds 0.3 are labelled with its channel (the nearer centre where two
    overlap); the background is ignored; no blob: 0, with a gradient path."""
    target = torch.zeros(1, 3, 20, 30)
    target[0, 0] = _blob(20, 30, 10.0, 8.0, 3.0)
    target[0, 2] = _blob(20, 30, 10.0, 14.0, 3.0)
    logits = torch.zeros(1, 3, 20, 30)
    logits[0, 0, :, :11] = 10.0  # channel 0 left of the midpoint, channel 2 right of it: all right
    logits[0, 2, :, 11:] = 10.0
    good = center_class_loss(logits, target)
    assert good < 1e-3
    swapped = center_class_loss(logits.flip(1), target)  # channel 0 and 2 exchanged: all wrong
    assert swapped > 5
    uniform = center_class_loss(torch.zeros(1, 3, 20, 30), target)
    assert abs(float(uniform) - float(torch.log(torch.tensor(3.0)))) < 1e-5
    # the background's logits do not matter
    noisy = logits.clone()
    noisy[0, :, :, 25:] = torch.randn(3, 20, 5) * 50
    assert torch.allclose(center_class_loss(noisy, target), good)
    empty = center_class_loss(torch.zeros(1, 3, 4, 4, requires_grad=True), torch.zeros(1, 3, 4, 4))
    assert float(empty.detach()) == 0.0 and empty.requires_grad


def test_a_factored_run_trains_center_and_class(tiny_root, tmp_path) -> None:
    """A tiny T-LESS-style run of the factored variant (two object ids, one channel each) lowers its center loss
    (class-agnostic focal + class cross-entropy) and writes weights that load with their factored spec."""
    torch.set_num_threads(2)
    root = tmp_path / "tless"
    assert main(["synth", "--layout", "tless", "--out", str(root), "--scenes", "1", "--views", "2", "--pbr-scenes",
                 "0", "--seed", "5", "--no-contact-sheets"]) == 0  # fmt: skip
    config = TrainConfig(dataset="tless", data_root=str(root), split="test", epochs=4, batch_size=2, lr=1e-2,
                         variant="tless-lean", factored_centers=True, width=0.5, seed=3, augment=False,
                         center_loss="focal", center_loss_weight=0.1, class_loss_weight=1.0)  # fmt: skip
    summary = train(config, tmp_path / "run", cache_dir=tmp_path / "cache", progress=False)
    centers = [r.train_center_loss for r in summary.history]
    assert centers[-1] < 0.8 * centers[0], centers
    weights = load_weights(tmp_path / "run" / WEIGHTS, dataset="tless")
    assert weights.model.spec.factored_centers and len(weights.channel_obj_ids) == weights.model.spec.center_channels
    assert weights.model.spec.name == "tless-lean+factored"  # --factored-centers on a variant without one
    payload = torch.load(tmp_path / "run" / WEIGHTS, weights_only=True)
    payload["channel_obj_ids"] = [i + 100 for i in payload["channel_obj_ids"]]  # the same network, other objects
    torch.save(payload, tmp_path / "other_ids.pt")
    with pytest.raises(ConfigError, match=r"--init-weights: its center channels are of object ids \[1\d\d"):
        train(replace(config, epochs=1, init_weights=str(tmp_path / "other_ids.pt")), tmp_path / "run2",
              cache_dir=tmp_path / "cache", progress=False)  # fmt: skip
    with pytest.raises(ConfigError, match="class-loss-weight"):
        _config(tiny_root, class_loss_weight=0.0)
    with pytest.raises(ConfigError, match="needs one center channel per object id"):  # DIMO: one shared channel
        train(_config(tiny_root, factored_centers=True), tmp_path / "dimo_factored", progress=False)


def test_validation_restricts_a_factored_networks_classes_per_sample() -> None:
    """Each sample's mask holds the channels of its own scene's ids; none without known ids."""
    from types import SimpleNamespace

    from bop_cender.net.train import _class_masks

    samples = SimpleNamespace(channel_obj_ids=(5, 6, 9), scene_obj_ids=[frozenset({5}), frozenset({6, 9, 100})])
    masks = _class_masks(samples, [1, 0])
    assert masks.tolist() == [[False, True, True], [True, False, False]]
    assert _class_masks(SimpleNamespace(channel_obj_ids=(5,), scene_obj_ids=None), [0]) is None


def test_the_class_loss_weight_binds_a_resume_of_a_factored_run_only(tiny_root) -> None:
    lean = _config(tiny_root)
    assert lean.same_run_as(_config(tiny_root, class_loss_weight=0.5))  # no class head: the weight does nothing
    factored = _config(tiny_root, dataset="tless", variant="tless-factored")
    assert not factored.same_run_as(replace(factored, class_loss_weight=0.5))
    assert factored.same_run_as(replace(factored, epochs=9))


def test_resuming_with_fewer_epochs_than_done_is_refused(tiny_root, tmp_path) -> None:
    """Its weights are of a later epoch than asked: the run said "trained 1 epoch (resumed after 2)" and exit 0."""
    config = _config(tiny_root, epochs=2, batch_size=4, augment=False, limit_scenes=1, val_split=None)
    train(config, tmp_path / "run", cache_dir=tmp_path / "cache", progress=False)
    before = (tmp_path / "run" / WEIGHTS).read_bytes()
    with pytest.raises(ConfigError, match=r"--epochs: .* holds 2 epochs already, more than --epochs 1"):
        train(replace(config, epochs=1), tmp_path / "run", resume=True, cache_dir=tmp_path / "cache", progress=False)
    assert (tmp_path / "run" / WEIGHTS).read_bytes() == before


def test_a_vote_run_learns_its_votes_resumes_exactly_and_guards_its_loss_weight(tiny_root, tmp_path) -> None:
    """dimo-votes (from random weights, augmented): the vote loss falls with the rest, a resumed run equals an
    uninterrupted one, the weights load with their votes, and the vote loss's weight binds a vote network only."""
    torch.set_num_threads(2)
    config = _config(tiny_root, variant="dimo-votes", width=0.5, epochs=4, batch_size=2, lr=1e-2, val_split=None,
                     center_loss="focal", center_loss_weight=0.1)  # fmt: skip
    cache = tmp_path / "cache"
    whole = train(config, tmp_path / "whole", cache_dir=cache, progress=False)
    centers = [r.train_center_loss for r in whole.history]  # focal centre loss plus the vote loss
    assert centers[-1] < 0.7 * centers[0], centers
    train(replace(config, epochs=2), tmp_path / "split", cache_dir=cache, progress=False)
    resumed = train(config, tmp_path / "split", resume=True, cache_dir=cache, progress=False)
    assert [r.train_loss for r in resumed.history] == [r.train_loss for r in whole.history]
    weights = load_weights(tmp_path / "split" / WEIGHTS, dataset="dimo")
    assert weights.model.spec.center_votes and weights.model.vote_head is not None
    assert not config.same_run_as(replace(config, vote_loss_weight=0.5))
    assert _config(tiny_root).same_run_as(_config(tiny_root, vote_loss_weight=0.5))  # no votes: it does nothing
    with pytest.raises(ConfigError, match="vote-loss-weight"):
        _config(tiny_root, vote_loss_weight=0.0)
    assert main(["train", "--dataset", "dimo", "--data-root", str(tiny_root), "--split", "real", "--variant",
                 "dimo-lean", "--vote-loss-weight", "2", "--out", str(tmp_path / "refused")]) == 2  # fmt: skip
    assert not (tmp_path / "refused").exists()
    paper = _config(tiny_root, variant="dimo", center_votes=True).network_spec(1)
    assert paper.center_votes and paper.name == "dimo+votes" and paper.channels == UNetSpec.dimo().channels
