"""Training augmentations: targets follow the image under flips and zoom, photometric ops leave them alone."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
import torch

from bop_cender.net.augment import (
    AugmentConfig,
    adjust_hue,
    adjust_sharpness,
    augment,
    hsv_to_rgb,
    rgb_to_hsv,
)

B, C, H, W = 2, 3, 32, 40
OFF = AugmentConfig.none()
#: Every photometric op on for every sample, geometry off.
PHOTOMETRIC = replace(
    OFF,
    brightness=(0.7, 1.3),
    contrast=(0.7, 1.3),
    hue=(-0.1, 0.1),
    blur_p=1.0,
    noise_p=1.0,
    sharpness_p=1.0,
    sharpness=(0.5, 1.5),
)
#: Everything on for every sample.
ALL_ON = replace(PHOTOMETRIC, hflip_p=1.0, vflip_p=1.0, scale=(1.0, 1.25))


def gen(seed: int = 0) -> torch.Generator:
    return torch.Generator(device="cpu").manual_seed(seed)


def inputs(device: torch.device | str = "cpu", seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = gen(1000 + seed)
    image = torch.rand((B, 3, H, W), generator=g)
    center = torch.rand((B, C, H, W), generator=g)
    curvature = torch.rand((B, H, W), generator=g)
    return image.to(device), center.to(device), curvature.to(device)


def blob_inputs(row: float, col: float, sigma: float = 1.5) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A Gaussian blob at pixel ``(row, col)`` (pixel-centre coordinates) in every map, the image's on grey."""
    v = torch.arange(H, dtype=torch.float32).view(H, 1)
    u = torch.arange(W, dtype=torch.float32).view(1, W)
    blob = torch.exp(-((v - row) ** 2 + (u - col) ** 2) / (2 * sigma**2))
    image = (0.2 + 0.7 * blob).expand(B, 3, H, W).clone()
    return image, blob.expand(B, C, H, W).clone(), blob.expand(B, H, W).clone()


def centroid(m: torch.Tensor) -> tuple[float, float]:
    """Weighted ``(row, col)`` centroid of a non-negative ``(H, W)`` map."""
    v = torch.arange(m.shape[0], dtype=m.dtype).view(-1, 1)
    u = torch.arange(m.shape[1], dtype=m.dtype).view(1, -1)
    return float((m * v).sum() / m.sum()), float((m * u).sum() / m.sum())


def argmax2d(m: torch.Tensor) -> tuple[int, int]:
    i = int(m.flatten().argmax())
    return i // m.shape[-1], i % m.shape[-1]


def test_imports_the_checkout_under_test():
    import bop_cender.net.augment as mod

    assert Path(mod.__file__).resolve().parents[2] == Path(__file__).resolve().parents[2]


def test_shapes_dtype_device_kept_and_inputs_untouched(device):
    image, center, curvature = inputs(device)
    before = [t.clone() for t in (image, center, curvature)]
    out = augment(image, center, curvature, AugmentConfig(), gen())
    for o, i in zip(out, (image, center, curvature), strict=True):
        assert o.shape == i.shape and o.dtype == i.dtype and o.device == i.device
        assert o.data_ptr() != i.data_ptr()
    for t, b in zip((image, center, curvature), before, strict=True):
        assert torch.equal(t, b)


def test_none_is_the_identity():
    image, center, curvature = inputs()
    out = augment(image, center, curvature, OFF, gen())
    for o, i in zip(out, (image, center, curvature), strict=True):
        assert torch.equal(o, i)


def test_same_seed_same_output_different_seed_different():
    image, center, curvature = inputs()
    a = augment(image, center, curvature, ALL_ON, gen(7))
    b = augment(image, center, curvature, ALL_ON, gen(7))
    c = augment(image, center, curvature, ALL_ON, gen(8))
    assert all(torch.equal(x, y) for x, y in zip(a, b, strict=True))
    assert not torch.allclose(a[0], c[0])
    assert not torch.allclose(a[1], c[1])  # the zoom factor differs too


def test_parameters_are_drawn_per_sample():
    image, center, curvature = inputs()
    image = image[:1].expand(B, -1, -1, -1)
    out = augment(image, center, curvature, PHOTOMETRIC, gen(3))[0]
    assert not torch.allclose(out[0], out[1])


@pytest.mark.parametrize(("flip", "field"), [(-1, "hflip_p"), (-2, "vflip_p")])
def test_flip_moves_image_and_targets_together(flip, field):
    image = torch.full((B, 3, H, W), 0.1)
    center = torch.zeros((B, C, H, W))
    curvature = torch.zeros((B, H, W))
    r, c = 5, 7
    image[:, :, r, c] = 1.0
    center[:, :, r, c] = 1.0
    curvature[:, r, c] = 1.0
    out_i, out_c, out_k = augment(image, center, curvature, replace(OFF, **{field: 1.0}), gen())
    expected = (r, W - 1 - c) if flip == -1 else (H - 1 - r, c)
    for b in range(B):
        assert argmax2d(out_i[b].mean(0)) == expected
        assert all(argmax2d(out_c[b, ch]) == expected for ch in range(C))
        assert argmax2d(out_k[b]) == expected
    assert torch.equal(out_c, center.flip(flip)) and torch.equal(out_k, curvature.flip(flip))


def test_half_probability_flips_some_samples_and_not_others():
    image = torch.rand((64, 3, 4, 5), generator=gen(1))
    out = augment(image, torch.zeros((64, 1, 4, 5)), torch.zeros((64, 4, 5)), replace(OFF, hflip_p=0.5), gen())[0]
    flipped = torch.tensor([torch.equal(o, i.flip(-1)) for o, i in zip(out, image, strict=True)])
    kept = torch.tensor([torch.equal(o, i) for o, i in zip(out, image, strict=True)])
    assert bool((flipped | kept).all()) and 10 < int(flipped.sum()) < 54


@pytest.mark.parametrize("s", [1.1, 1.25])
def test_zoom_moves_a_point_at_r_to_s_r_in_image_and_targets(s):
    row, col = 10.0, 30.0  # pixel centres; the image centre is at (H / 2 - 0.5, W / 2 - 0.5) in these coordinates
    image, center, curvature = blob_inputs(row, col)
    out_i, out_c, out_k = augment(image, center, curvature, replace(OFF, scale=(s, s)), gen())
    cy, cx = H / 2 - 0.5, W / 2 - 0.5
    expected = (cy + s * (row - cy), cx + s * (col - cx))
    for b in range(B):
        got_image = centroid(out_i[b].mean(0) - 0.2)
        got_center = centroid(out_c[b, 0])
        got_curv = centroid(out_k[b])
        for got in (got_image, got_center, got_curv):
            assert got == pytest.approx(expected, abs=0.05)
        assert argmax2d(out_c[b, 0]) == argmax2d(out_i[b].mean(0)) == argmax2d(out_k[b])
        # The blob is widened by s as well (bilinear: zoomed, not just moved).
        assert float(out_c[b, 0].sum()) == pytest.approx(s**2 * float(center[b, 0].sum()), rel=0.02)


def test_zoom_draws_one_factor_per_sample_for_image_and_targets():
    image, center, curvature = blob_inputs(6.0, 8.0)
    out_i, out_c, out_k = augment(image, center, curvature, replace(OFF, scale=(1.0, 1.25)), gen(5))
    cy, cx = H / 2 - 0.5, W / 2 - 0.5
    factors = []
    for b in range(B):
        r_c, c_c = centroid(out_c[b, 0])
        r_i, c_i = centroid(out_i[b].mean(0) - 0.2)
        assert (r_i, c_i) == pytest.approx((r_c, c_c), abs=0.05)
        assert centroid(out_k[b]) == pytest.approx((r_c, c_c), abs=0.05)
        factors.append((c_c - cx) / (8.0 - cx))
        assert (r_c - cy) / (6.0 - cy) == pytest.approx(factors[-1], abs=0.01)
    assert all(1.0 - 1e-3 <= f <= 1.25 + 1e-3 for f in factors) and abs(factors[0] - factors[1]) > 1e-3


def test_photometric_ops_leave_the_targets_alone():
    image, center, curvature = inputs()
    out_i, out_c, out_k = augment(image, center, curvature, PHOTOMETRIC, gen())
    assert torch.equal(out_c, center) and torch.equal(out_k, curvature)
    assert not torch.allclose(out_i, image)


@pytest.mark.parametrize(
    "config", [AugmentConfig(), ALL_ON, replace(ALL_ON, brightness=(1.3, 1.3), contrast=(1.3, 1.3))]
)
def test_values_stay_in_unit_range(config):
    image, center, curvature = inputs()
    for seed in range(3):
        for out in augment(image, center, curvature, config, gen(seed)):
            assert float(out.min()) >= 0.0 and float(out.max()) <= 1.0


def test_hue_shift_zero_is_identity_and_hsv_round_trips():
    image, _, _ = inputs()
    assert torch.allclose(adjust_hue(image, torch.zeros(B)), image, atol=1e-5)
    assert torch.allclose(hsv_to_rgb(rgb_to_hsv(image)), image, atol=1e-5)
    out = augment(image, *inputs()[1:], replace(OFF, hue=(0.0, 0.0)), gen())[0]
    assert torch.equal(out, image)


def test_hue_third_of_the_circle_maps_red_to_green_to_blue():
    red = torch.zeros((B, 3, 4, 5))
    red[:, 0] = 1.0
    green = adjust_hue(red, torch.full((B,), 1.0 / 3.0))
    assert torch.allclose(green, torch.roll(red, 1, dims=1), atol=1e-5)
    blue = adjust_hue(red, torch.full((B,), -1.0 / 3.0))
    assert torch.allclose(blue, torch.roll(red, 2, dims=1), atol=1e-5)
    # Through augment: a forced shift of 1/3.
    out = augment(red, torch.zeros((B, 1, 4, 5)), torch.zeros((B, 4, 5)), replace(OFF, hue=(1 / 3, 1 / 3)), gen())[0]
    assert torch.allclose(out, green, atol=1e-5)


def test_hue_keeps_grey_and_saturation_and_value():
    grey = torch.full((B, 3, 4, 5), 0.4)
    assert torch.allclose(adjust_hue(grey, torch.full((B,), 0.25)), grey, atol=1e-6)
    image, _, _ = inputs()
    hsv_in = rgb_to_hsv(image)
    hsv_out = rgb_to_hsv(adjust_hue(image, torch.full((B,), 0.1)))
    assert torch.allclose(hsv_in[:, 1:], hsv_out[:, 1:], atol=1e-4)


def test_brightness_factor_scales_the_mean():
    image = 0.5 * inputs()[0]  # in [0, 0.5]: no clipping at 1.3
    for f in (0.7, 1.3):
        out = augment(image, *inputs()[1:], replace(OFF, brightness=(f, f)), gen())[0]
        assert float(out.mean()) == pytest.approx(f * float(image.mean()), rel=1e-5)


def test_contrast_keeps_the_grey_mean_and_scales_deviations():
    image = 0.25 + 0.5 * inputs()[0]
    out = augment(image, *inputs()[1:], replace(OFF, contrast=(0.7, 0.7)), gen())[0]
    assert float(out.mean()) == pytest.approx(float(image.mean()), abs=0.02)
    assert float(out.std()) == pytest.approx(0.7 * float(image.std()), rel=0.02)


def test_blur_sigma_005_is_all_but_the_identity_and_a_wide_one_blurs():
    image, center, curvature = inputs()
    out = augment(image, center, curvature, replace(OFF, blur_p=1.0), gen())[0]
    assert float((out - image).abs().max()) < 1e-4
    wide = augment(image, center, curvature, replace(OFF, blur_p=1.0, blur_sigma=1.0), gen())[0]
    assert float((wide - image).abs().mean()) > 0.05
    assert float(wide.mean()) == pytest.approx(float(image.mean()), abs=5e-3)


def test_noise_has_the_configured_std():
    image = torch.full((B, 3, H, W), 0.5)
    out = augment(image, *inputs()[1:], replace(OFF, noise_p=1.0, noise_std=0.02), gen())[0]
    assert float((out - image).std()) == pytest.approx(0.02, rel=0.1)


def test_sharpness_factor_one_is_identity_zero_smooths_borders_kept():
    image, _, _ = inputs()
    assert torch.allclose(adjust_sharpness(image, torch.ones(B)), image, atol=1e-6)
    smooth = adjust_sharpness(image, torch.zeros(B))
    k = torch.ones(3, 3)
    k[1, 1] = 5.0
    expected = (image[0, 0, 4:7, 9:12] * k).sum() / 13.0
    assert float(smooth[0, 0, 5, 10]) == pytest.approx(float(expected), abs=1e-6)
    for index in ((..., 0, slice(None)), (..., -1, slice(None)), (..., slice(None), 0), (..., slice(None), -1)):
        assert torch.equal(smooth[index], image[index])
    sharp = adjust_sharpness(image, torch.full((B,), 1.5))
    assert float(sharp[..., 1:-1, 1:-1].std()) > float(image[..., 1:-1, 1:-1].std())


@pytest.mark.parametrize(
    ("image_shape", "center_shape", "curv_shape", "name"),
    [
        ((B, 1, H, W), (B, C, H, W), (B, H, W), "image"),
        ((3, H, W), (B, C, H, W), (B, H, W), "image"),
        ((B, 3, H, W), (B, C, H, W + 1), (B, H, W), "center"),
        ((B, 3, H, W), (B + 1, C, H, W), (B, H, W), "center"),
        ((B, 3, H, W), (B, C, H, W), (B, 1, H, W), "curvature"),
        ((B, 3, H, W), (B, C, H, W), (B, H - 1, W), "curvature"),
    ],
)
def test_bad_shapes_raise(image_shape, center_shape, curv_shape, name):
    with pytest.raises(ValueError, match=name):
        augment(torch.rand(image_shape), torch.rand(center_shape), torch.rand(curv_shape), AugmentConfig(), gen())


def test_bad_config_raises():
    with pytest.raises(ValueError, match="hflip_p"):
        AugmentConfig(hflip_p=1.5)
    with pytest.raises(ValueError, match="scale"):
        AugmentConfig(scale=(1.25, 1.0))
    with pytest.raises(ValueError, match="blur_kernel"):
        AugmentConfig(blur_kernel=4)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cpu_and_cuda_agree():
    for config in (AugmentConfig(), ALL_ON):
        cpu = augment(*inputs("cpu"), config, gen(11))
        cuda = augment(*inputs("cuda"), config, gen(11))
        for a, b in zip(cpu, cuda, strict=True):
            assert b.device.type == "cuda"
            assert torch.allclose(a, b.cpu(), atol=1e-5)
