"""``train --init-weights``: which weights may start which network, and the widening of a shared centre channel."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from bop_cender.errors import ConfigError
from bop_cender.net.init_from import can_start_from, start_from, widens_centers
from bop_cender.net.train import network_spec_of
from bop_cender.net.unet import UNet
from bop_cender.net.weights import load_weights, shipped_weights_path


@pytest.fixture(scope="module")
def dimo_weights() -> Path:
    return shipped_weights_path("dimo")


def test_a_shared_centre_channel_starts_a_factored_head_as_the_same_centres_split_evenly(dimo_weights) -> None:
    """Every channel of the widened network starts as the DIMO network's centre probability / K, and its curvature
    is the DIMO network's, bit for bit in the shared layers."""
    dimo = load_weights(dimo_weights).model.eval()
    ids = (1, 2, 3, 4, 5, 6)
    spec = network_spec_of(dimo.spec.name, dimo.spec.width, len(ids), factored_centers=True)
    model = UNet(spec).eval()
    start_from(model, dimo_weights, ids)
    image = torch.rand(1, 3, 64, 96, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        center, curvature = dimo(image)
        wide_center, wide_curvature = model(image)
    assert wide_center.shape == (1, len(ids), 64, 96)
    torch.testing.assert_close(wide_curvature, curvature)
    expected = torch.sigmoid(center).expand(-1, len(ids), -1, -1) / len(ids)
    torch.testing.assert_close(torch.sigmoid(wide_center), expected, rtol=1e-5, atol=1e-7)


def test_what_may_start_what(dimo_weights) -> None:
    dimo = load_weights(dimo_weights).model.spec
    factored = network_spec_of(dimo.name, dimo.width, 6, factored_centers=True)
    independent = network_spec_of(dimo.name, dimo.width, 6)
    assert widens_centers(dimo, factored) and not can_start_from(dimo, factored)
    assert not widens_centers(dimo, independent) and not can_start_from(dimo, independent)
    assert not widens_centers(factored, factored) and can_start_from(factored, factored)
    lean = network_spec_of("dimo-lean", dimo.width, 1)  # fewer modules than the weights: no
    assert not widens_centers(dimo, network_spec_of("dimo-lean", dimo.width, 6, factored_centers=True))
    assert not can_start_from(dimo, lean) and can_start_from(lean, dimo)


def test_weights_that_cannot_start_the_network_are_refused_naming_the_file(dimo_weights, tmp_path) -> None:
    independent = UNet(network_spec_of("dimo-context", 1.0, 6))
    with pytest.raises(ConfigError, match=r"--init-weights: its network \(dimo-context, 1 center channels\)") as e:
        start_from(independent, dimo_weights, (1, 2, 3, 4, 5, 6))
    assert e.value.file == str(dimo_weights) and "start a run with --factored-centers" in str(e.value)
    same = UNet(network_spec_of("dimo-context", 1.0, 1))
    with pytest.raises(ConfigError, match=r"center channels are of object ids none \(one shared channel\)"):
        start_from(same, dimo_weights, (1, 2))
    start_from(same, dimo_weights, None)  # the same network, the same shared channel
