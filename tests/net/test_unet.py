"""The U-Net's variants: output shapes at any size, separate heads, spec round trip."""

from __future__ import annotations

import pytest
import torch

from bop_cender.net.unet import UNet, UNetSpec, count_parameters, factored_center_logits


@pytest.mark.parametrize(
    ("spec", "size"),
    [
        (UNetSpec.dimo(width=0.25), (32, 40)),
        (UNetSpec.dimo(width=0.25), (31, 45)),  # odd: padded to the stride and cropped back
        (UNetSpec.dimo_lean(), (37, 50)),
        (UNetSpec.dimo_context(), (37, 50)),
        (UNetSpec.dimo_refine(), (37, 50)),
        (UNetSpec.tless(center_channels=5, width=0.125), (54, 72)),
        (UNetSpec.tless(center_channels=5, width=0.125), (50, 61)),
        (UNetSpec.tless_lean(center_channels=3), (40, 41)),
        (UNetSpec.tless_factored(center_channels=4), (40, 41)),
        (UNetSpec.tless_refine(center_channels=4), (40, 41)),
    ],
)
def test_outputs_have_the_input_size_and_the_spec_channels(spec, size, device) -> None:
    model = UNet(spec).to(device).eval()
    image = torch.rand(2, 3, *size, device=device)
    with torch.no_grad():
        center, curvature = model(image)
    assert center.shape == (2, spec.center_channels, *size) and curvature.shape == (2, *size)
    assert center.device == image.device and center.dtype == torch.float32
    assert torch.isfinite(center).all() and torch.isfinite(curvature).all()


def test_paper_variants_follow_the_appendix_tables() -> None:
    dimo, tless = UNetSpec.dimo(), UNetSpec.tless()
    assert (dimo.channels, dimo.strides, dimo.head_channels, dimo.center_channels) == ((32, 32, 64), (1, 2, 2), 32, 1)
    assert (tless.channels, tless.strides, tless.head_channels, tless.center_channels) == (
        (64, 128, 256),
        (3, 1, 3),
        128,
        30,
    )
    assert dimo.total_stride == 4 and tless.total_stride == 9
    model = UNet(dimo)
    assert model.e1.body[0].out_channels == 32 and model.e3.body[0].out_channels == 64
    feats = {}
    hooks = [
        getattr(model, n).register_forward_hook(lambda m, i, o, n=n: feats.__setitem__(n, o.shape))
        for n in ("e1", "e2", "e3", "d1")
    ]
    with torch.no_grad():
        model.eval()(torch.rand(1, 3, 256, 320))
    for h in hooks:
        h.remove()
    assert feats["e1"][-2:] == (256, 320) and feats["e2"][-2:] == (128, 160) and feats["e3"][-2:] == (64, 80)
    assert feats["d1"][1:] == (64, 256, 320)


def test_heads_are_separate_and_logits_are_unbounded() -> None:
    model = UNet(UNetSpec.dimo_lean())
    assert not set(map(id, model.center_head.parameters())) & set(map(id, model.curvature_head.parameters()))
    with torch.no_grad():
        model.center_head.body[-1].bias.fill_(-20.0)
        center, curvature = model.eval()(torch.rand(1, 3, 32, 32))
    assert center.max() < -10 and curvature.min() > -10  # one head changed, the other did not


def test_width_scales_the_features_and_the_spec_round_trips() -> None:
    small, large = UNet(UNetSpec.dimo(width=0.5)), UNet(UNetSpec.dimo(width=1.0))
    assert count_parameters(small) < count_parameters(large) / 3
    spec = UNetSpec.tless_lean(center_channels=7, width=0.75)
    assert UNetSpec.from_dict(spec.as_dict()) == spec
    assert UNetSpec.named("tless", center_channels=4).center_channels == 4
    with pytest.raises(ValueError, match="unknown network variant"):
        UNetSpec.named("resnet")
    with pytest.raises(ValueError, match="width"):
        UNetSpec.dimo(width=0)
    with pytest.raises(ValueError, match="image must be"):
        UNet(UNetSpec.dimo_lean())(torch.rand(1, 1, 16, 16))


def _receptive_radius(model: UNet, size: tuple[int, int] = (256, 320)) -> int:
    """How far (pixels) from the centre pixel an input change still reaches the centre logit (eval mode)."""
    model.eval()
    image = torch.rand(1, 3, *size, generator=torch.Generator().manual_seed(0)).requires_grad_()
    center, _ = model(image)
    center[0, 0, size[0] // 2, size[1] // 2].backward()
    reached = image.grad.abs().sum(1)[0] > 0
    rows = torch.nonzero(reached.any(1)).flatten()
    return int(max(size[0] // 2 - rows.min(), rows.max() - size[0] // 2))


def test_the_context_variant_widens_the_receptive_field_and_old_specs_have_none() -> None:
    torch.manual_seed(0)
    lean, context = UNet(UNetSpec.dimo_lean()), UNet(UNetSpec.dimo_context())
    for layer in context.context.layers:  # trained: the residuals are no longer zero
        torch.nn.init.ones_(layer[1].weight)
    assert _receptive_radius(lean) < 70 < 120 < _receptive_radius(context)  # 61 and the image edge (128)
    assert count_parameters(context) < 1.3 * count_parameters(lean)
    spec = UNetSpec.named("dimo-context")
    assert spec.context_dilations == (2, 4, 8) and UNetSpec.from_dict(spec.as_dict()) == spec
    old = UNetSpec.dimo_lean().as_dict()
    del old["context_dilations"]  # a weights file written before the field existed
    assert UNetSpec.from_dict(old) == UNetSpec.dimo_lean() and UNet(UNetSpec.from_dict(old)).context is None
    with pytest.raises(ValueError, match="dilations"):
        UNetSpec(context_dilations=(0,))


@pytest.mark.parametrize(
    ("base", "grown", "prefix", "new_weight"),
    [
        (UNetSpec.dimo_lean, UNetSpec.dimo_context, "context.", lambda net: net.context.layers[0][1].weight),
        (UNetSpec.dimo_context, UNetSpec.dimo_refine, "refine.", lambda net: net.refine.out_weight),
    ],
    ids=["context-from-lean", "refine-from-context"],
)
def test_a_grown_network_started_from_the_smaller_ones_weights_computes_what_they_did_and_learns(
    base, grown, prefix, new_weight
) -> None:
    """The context blocks and the curvature refinement start as the identity: the smaller network's weights give
    the same outputs, and the new part still gets gradients (it can leave zero)."""
    torch.manual_seed(1)
    small, big = UNet(base()).eval(), UNet(grown()).eval()
    missing, unexpected = big.load_state_dict(small.state_dict(), strict=False)
    assert not unexpected and missing and all(k.startswith(prefix) for k in missing)
    image = torch.rand(2, 3, 48, 64)
    with torch.no_grad():
        for a, b in zip(small(image), big(image), strict=True):
            assert torch.equal(a, b)
    big.train()
    center, curvature = big(image)
    (center.sum() + curvature.sum()).backward()
    assert new_weight(big).grad.abs().sum() > 0
    assert UNet(UNetSpec.dimo_context()).refine is None and UNet(UNetSpec.dimo_lean()).context is None


def test_the_refinement_draws_a_one_pixel_line_that_an_upsampled_logit_cannot() -> None:
    """A vertical 1-pixel line in the image is the target; the logit from half resolution (the GT averaged over
    2x2 pixels, upsampled) smears it over 2-3 columns. Trained alone for a few steps, the refinement puts it back
    on its column: the BCE falls well below the coarse logit's, and the line's column wins in every row."""
    torch.manual_seed(4)
    from bop_cender.net.unet import _Refine, _resize

    H, W = 16, 20
    image = torch.zeros(4, 3, H, W)
    target = torch.zeros(4, 1, H, W)
    for b, col in enumerate((3, 8, 11, 16)):  # odd and even columns: half a coarse pixel either side
        image[b, :, :, col] = 1.0
        target[b, 0, :, col] = 1.0
    coarse = torch.logit(_resize(torch.nn.functional.avg_pool2d(target, 2), (H, W)).clamp(1e-3, 1 - 1e-3))
    features = torch.nn.functional.avg_pool2d(image, 2)[:, :1].repeat(1, 4, 1, 1)  # (B, 4, H/2, W/2)
    module = _Refine(4, 8)
    bce = torch.nn.functional.binary_cross_entropy_with_logits
    before = bce(module(image, features, coarse), target).item()
    assert before == pytest.approx(bce(coarse, target).item())  # starts as the identity
    optimiser = torch.optim.Adam(module.parameters(), lr=3e-2)
    for _ in range(150):
        optimiser.zero_grad()
        loss = bce(module(image, features, coarse), target)
        loss.backward()
        optimiser.step()
    module.eval()
    with torch.no_grad():
        refined = module(image, features, coarse)
    assert bce(refined, target).item() < 0.5 * before
    assert torch.equal(refined[:, 0].argmax(dim=-1), target[:, 0].argmax(dim=-1))


@pytest.mark.parametrize(
    ("variant", "field", "value"),
    [("dimo-refine", "refine_channels", 8), ("dimo-centers", "center_branch_channels", 48)],
)
def test_a_variants_spec_round_trips_and_a_file_without_its_field_reads_as_without_it(variant, field, value) -> None:
    spec = UNetSpec.named(variant)
    assert getattr(spec, field) == value and spec.context_dilations == (2, 4, 8)
    assert UNetSpec.from_dict(spec.as_dict()) == spec
    old = UNetSpec.dimo_context().as_dict()
    del old[field]  # a weights file written before the field existed
    assert UNetSpec.from_dict(old) == UNetSpec.dimo_context()


def test_the_refinement_needs_a_first_stride_above_one() -> None:
    with pytest.raises(ValueError, match="first stride above 1"):
        UNetSpec(refine_channels=8)  # the paper's DIMO network: heads at full resolution already
    with pytest.raises(ValueError, match="refine channels"):
        UNetSpec(strides=(2, 2, 2), refine_channels=-1)


def test_the_center_branch_starts_as_the_identity() -> None:
    """dimo-context weights start a dimo-centers network: its branch adds zero, so the same maps to the bit; once
    the branch's output convolution is not zero the centres change and the curvature does not."""
    spec = UNetSpec.named("dimo-centers")
    with pytest.raises(ValueError, match="center branch channels"):
        UNetSpec(center_branch_channels=-1)
    torch.manual_seed(3)
    context = UNet(UNetSpec.dimo_context()).eval()
    centers = UNet(spec).eval()
    missing, unexpected = centers.load_state_dict(context.state_dict(), strict=False)
    assert not unexpected and missing and all(k.startswith("center_branch.") for k in missing)
    image = torch.rand(2, 3, 72, 88)  # not a multiple of the stride 8: padded and cropped back
    with torch.no_grad():
        c0, k0 = context(image)
        c1, k1 = centers(image)
        assert c1.shape == (2, 1, 72, 88) and k1.shape == (2, 72, 88)
        assert torch.equal(c0, c1) and torch.equal(k0, k1)
        torch.nn.init.normal_(centers.center_branch.out.weight, std=0.5)
        c2, k2 = centers(image)
    assert not torch.allclose(c2, c0) and torch.equal(k2, k0)


def test_factored_centers_are_a_center_probability_times_a_class_probability() -> None:
    """sigmoid of the combined logit of channel k is sigmoid(center) * softmax(classes)_k, finite even where the
    raw logits are extreme; the channels of one pixel sum to the center probability."""
    torch.manual_seed(2)
    raw = torch.randn(2, 1 + 5, 6, 7) * 4
    raw[0, 0, 0, 0], raw[0, 1, 0, 0] = 60.0, 80.0  # p -> 1 in channel 0: the logit stays finite
    raw[1, 0, 0, 0] = -90.0
    combined = factored_center_logits(raw)
    assert combined.shape == (2, 5, 6, 7) and torch.isfinite(combined).all()
    p = torch.sigmoid(combined)
    expected = torch.sigmoid(raw[:, :1]) * torch.softmax(raw[:, 1:], dim=1)
    assert torch.allclose(p, expected, atol=1e-6)
    assert torch.allclose(p.sum(1), torch.sigmoid(raw[:, 0]), atol=1e-5)
    assert combined[0, 0, 0, 0] > 10  # near-certain: a large logit, not a clamp at 0


def test_the_factored_variant_outputs_one_more_raw_channel_and_round_trips() -> None:
    spec = UNetSpec.named("tless-factored", center_channels=6)
    assert spec.factored_centers and spec.context_dilations and UNetSpec.from_dict(spec.as_dict()) == spec
    model = UNet(spec).eval()
    image = torch.rand(1, 3, 36, 48)
    with torch.no_grad():
        raw, curvature_raw = model.forward_raw(image)
        center, curvature = model(image)
    assert raw.shape == (1, 7, 36, 48) and center.shape == (1, 6, 36, 48)
    assert torch.allclose(center, factored_center_logits(raw)) and torch.equal(curvature, curvature_raw)
    with torch.no_grad():
        p_center, p_curvature = model.probabilities(image)  # direct, not through the combined logits
    assert torch.allclose(p_center, torch.sigmoid(center), atol=1e-6)
    assert torch.allclose(p_curvature, torch.sigmoid(curvature), atol=1e-6)
    lean = UNet(UNetSpec.dimo_lean(width=0.5)).eval()
    with torch.no_grad():
        assert torch.allclose(lean.probabilities(image)[0], torch.sigmoid(lean(image)[0]))
    old = UNetSpec.tless_lean(center_channels=6).as_dict()
    del old["factored_centers"]  # a weights file written before the field existed
    assert not UNetSpec.from_dict(old).factored_centers
    with pytest.raises(ValueError, match="at least 2 center channels"):
        UNetSpec(center_channels=1, factored_centers=True)
