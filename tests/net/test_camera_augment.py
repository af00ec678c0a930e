"""The camera augmentation (issue 42's lever): seeded, image-only, in range, each operation doing what it says, and a
training run that uses it."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))
from test_train import _config, tiny_root  # noqa: E402, F401  (the fixture is shared)

from bop_cender.errors import ConfigError  # noqa: E402
from bop_cender.net import camera_augment as cam  # noqa: E402
from bop_cender.net.camera_augment import camera_augment, gaussian_blur_per_sample  # noqa: E402
from bop_cender.net.train import CHECKPOINT, WEIGHTS, TrainConfig, train  # noqa: E402
from bop_cender.net.weights import load_weights  # noqa: E402


def _images(seed: int = 0, shape=(6, 3, 40, 52)) -> torch.Tensor:
    return torch.rand(shape, generator=torch.Generator().manual_seed(seed))


def test_the_same_seed_gives_the_same_cameras_and_the_input_is_untouched() -> None:
    image = _images()
    before = image.clone()
    a = camera_augment(image, torch.Generator().manual_seed(7))
    b = camera_augment(image, torch.Generator().manual_seed(7))
    c = camera_augment(image, torch.Generator().manual_seed(8))
    assert torch.equal(a, b) and not torch.equal(a, c) and torch.equal(image, before)
    assert a.shape == image.shape and a.dtype == image.dtype and a.min() >= 0 and a.max() <= 1
    assert (a - image).abs().mean() > 0.01  # it changes the images


def test_every_operation_is_drawn_at_its_rate(monkeypatch) -> None:
    """Over many samples each operation applies about as often as its probability says: with all but one switched
    off, the share of changed samples is that one's rate."""
    image = _images(1, shape=(400, 3, 12, 12)) * 0.8 + 0.1
    rates = {"CAST_P": cam.CAST_P, "TONE_P": cam.TONE_P, "BLUR_P": cam.BLUR_P, "LOWRES_P": cam.LOWRES_P,
             "NOISE_P": cam.NOISE_P, "GREY_P": cam.GREY_P}  # fmt: skip
    for name, rate in rates.items():
        for other in rates:
            monkeypatch.setattr(cam, other, rate if other == name else 0.0)
        out = camera_augment(image, torch.Generator().manual_seed(3))
        changed = ((out - image).abs().amax(dim=(1, 2, 3)) > 1e-6).float().mean().item()
        assert abs(changed - rate) < 0.08, (name, changed, rate)


def test_the_blur_keeps_a_flat_image_and_smooths_more_with_a_larger_sigma() -> None:
    flat = torch.full((2, 3, 20, 24), 0.3)
    torch.testing.assert_close(gaussian_blur_per_sample(flat, torch.tensor([0.5, 1.5])), flat)
    noise = _images(2, shape=(1, 3, 30, 30)).expand(2, 3, 30, 30).contiguous()
    out = gaussian_blur_per_sample(noise, torch.tensor([0.5, 1.5]))
    assert out[1].std() < out[0].std() < noise[0].std()
    torch.testing.assert_close(out.mean(dim=(2, 3)), noise.mean(dim=(2, 3)), atol=0.02, rtol=0)
    tiny = gaussian_blur_per_sample(_images(3, shape=(1, 3, 4, 4)), torch.tensor([1.0]))  # smaller than the kernel
    assert tiny.shape == (1, 3, 4, 4)


def test_grey_gives_equal_channels_and_an_empty_batch_passes(monkeypatch) -> None:
    for name in ("CAST_P", "TONE_P", "BLUR_P", "LOWRES_P", "NOISE_P"):
        monkeypatch.setattr(cam, name, 0.0)
    monkeypatch.setattr(cam, "GREY_P", 1.0)
    out = camera_augment(_images(), torch.Generator().manual_seed(0))
    assert torch.equal(out[:, 0], out[:, 1]) and torch.equal(out[:, 1], out[:, 2])
    assert camera_augment(torch.zeros((0, 3, 8, 8)), torch.Generator()).shape == (0, 3, 8, 8)


def test_bad_inputs_are_refused() -> None:
    with pytest.raises(ValueError, match="B, 3, H, W"):
        camera_augment(torch.rand(3, 8, 8), torch.Generator())
    with pytest.raises(ValueError, match="B, 3, H, W"):
        camera_augment(torch.zeros((1, 3, 8, 8), dtype=torch.uint8), torch.Generator())
    if torch.cuda.is_available():
        with pytest.raises(ValueError, match="CPU"):
            camera_augment(torch.rand(1, 3, 8, 8), torch.Generator(device="cuda"))


def test_a_run_with_the_lever_trains_otherwise_and_records_the_flag(tiny_root, tmp_path) -> None:  # noqa: F811
    config = _config(tiny_root, epochs=1, val_split=None, camera_augment=True)
    train(config, tmp_path / "with", progress=False)
    train(_config(tiny_root, epochs=1, val_split=None), tmp_path / "without", progress=False)
    with_lever, without = load_weights(tmp_path / "with" / WEIGHTS), load_weights(tmp_path / "without" / WEIGHTS)
    pairs = zip(with_lever.model.state_dict().values(), without.model.state_dict().values(), strict=True)
    assert any(not torch.equal(a, b) for a, b in pairs)
    assert load_weights(tmp_path / "with" / CHECKPOINT).extra["config"]["camera_augment"] is True
    assert json.loads((tmp_path / "with" / "config.json").read_text())["camera_augment"] is True


def test_the_lever_needs_the_paper_augmentations_and_old_configs_load_without_it(tiny_root) -> None:  # noqa: F811
    with pytest.raises(ConfigError, match="--no-augment"):
        _config(tiny_root, augment=False, camera_augment=True)
    old = _config(tiny_root).as_dict()
    del old["camera_augment"]  # a checkpoint written before the lever existed
    assert TrainConfig(**{**old, "crop": None}).camera_augment is False


def test_the_command_line_refuses_the_lever_without_the_paper_augmentations(tiny_root, tmp_path, capsys) -> None:  # noqa: F811
    from bop_cender.cli import main

    out = tmp_path / "refused"
    assert main(["train", "--dataset", "dimo", "--data-root", str(tiny_root), "--split", "real", "--no-augment",
                 "--camera-augment", "--out", str(out)]) == 2  # fmt: skip
    assert "--camera-augment" in capsys.readouterr().err and not out.exists()
