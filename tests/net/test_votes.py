"""Centre votes: targets from a render, dense maps, the loss, the vote map, augmentations and the network's use."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).parents[1]))
import method_data  # noqa: E402

from bop_cender.data.dimo import open_dimo  # noqa: E402
from bop_cender.meshes import MeshCache  # noqa: E402
from bop_cender.net.augment import AugmentConfig, augment, augment_with_votes  # noqa: E402
from bop_cender.net.samples import load_samples  # noqa: E402
from bop_cender.net.targets import TargetConfig, scene_targets, scene_targets_with_votes  # noqa: E402
from bop_cender.net.unet import UNet, UNetSpec  # noqa: E402
from bop_cender.net.votes import (  # noqa: E402
    LOG_AREA_MEAN,
    LOG_AREA_SCALE,
    dense_vote_targets,
    gaussian_peak_blur,
    vote_loss,
    vote_map,
    vote_targets,
)


def _two_parts(H: int = 40, W: int = 60):
    """An id map of two objects: a 12x10 block whose centre lies inside it and an L whose centre lies off it."""
    instance = torch.full((1, H, W), -1, dtype=torch.int64)
    instance[0, 5:15, 4:16] = 0  # block: pixels u 4..15, v 5..14 -> centre (10, 10) in continuous coordinates
    instance[0, 20:36, 30:33] = 1  # an L: a vertical leg ...
    instance[0, 33:36, 30:48] = 1  # ... and a horizontal one; its box centre (39, 28) is in the air
    centres = np.array([[[10.0, 10.0], [39.0, 28.0]]])
    return instance, centres


def _perfect_raw(dense: torch.Tensor) -> torch.Tensor:
    """The vote head's output that reproduces ``dense`` targets exactly."""
    fg = dense[:, 0]
    raw = torch.zeros_like(dense)
    raw[:, 0] = torch.where(fg > 0.5, 12.0, -12.0)
    raw[:, 1:3] = dense[:, 1:3] / torch.exp(0.5 * dense[:, 3:4])  # in units of sqrt(area)
    raw[:, 3] = torch.where(fg > 0.5, (dense[:, 3] - LOG_AREA_MEAN) / LOG_AREA_SCALE, torch.zeros_like(fg))
    return raw


def test_vote_targets_point_every_pixel_of_a_part_at_its_centre() -> None:
    instance, centres = _two_parts()
    targets = vote_targets(instance, centres, np.array([[True, True]]))
    assert targets.ids.dtype == np.uint8 and targets.ids.shape == (1, 40, 60)
    assert np.array_equal(np.unique(targets.ids), [0, 1, 2])
    table = targets.tables[0]
    assert table.shape == (2, 3) and table[:, 2].tolist() == [120.0, 16 * 3 + 3 * 15]  # areas in pixels
    dense = dense_vote_targets(torch.from_numpy(targets.ids), targets.tables)
    assert dense.shape == (1, 4, 40, 60)
    fg = dense[0, 0] > 0
    v, u = torch.nonzero(fg, as_tuple=True)
    target_x = u.float() + 0.5 + dense[0, 1][fg]
    target_y = v.float() + 0.5 + dense[0, 2][fg]
    which = torch.from_numpy(targets.ids[0]).long()[fg] - 1
    assert torch.allclose(target_x, torch.tensor(centres[0, :, 0], dtype=torch.float32)[which])
    assert torch.allclose(target_y, torch.tensor(centres[0, :, 1], dtype=torch.float32)[which])
    assert torch.allclose(dense[0, 3][fg], torch.log(torch.tensor(table[:, 2]))[which])
    assert float(dense[0, 1:][:, ~fg].abs().max()) == 0.0  # nothing where nothing votes
    # an object that does not vote in the view (no centre blob: too hidden) is background
    only_block = vote_targets(instance, centres, np.array([[True, False]]))
    assert np.array_equal(np.unique(only_block.ids), [0, 1]) and len(only_block.tables[0]) == 1


def test_perfect_votes_make_a_peak_of_one_at_each_centre_even_off_the_part() -> None:
    instance, centres = _two_parts()
    targets = vote_targets(instance, centres, np.array([[True, True]]))
    dense = dense_vote_targets(torch.from_numpy(targets.ids), targets.tables)
    voted = vote_map(_perfect_raw(dense), sigma_px=2.0)
    assert voted.shape == (1, 1, 40, 60)
    for x, y in centres[0]:
        u, v = int(x - 0.5), int(y - 0.5)  # the pixels around the centre share its votes
        window = voted[0, 0, v : v + 2, u : u + 2]
        assert float(window.max()) == pytest.approx(float(voted[0, 0].max()), abs=0.1)
        assert float(window.max()) > 0.85
    assert instance[0, 27, 38] == -1  # the L's centre shows nothing: a head reading the pixel sees background
    far = voted[0, 0].clone()
    far[0:20, 0:22] = 0
    far[18:38, 28:50] = 0
    assert float(far.max()) < 1e-3  # nowhere else
    # half of a part's votes 6 px off: a second, lower peak; the blur's peak stays 1, not a unit sum
    assert float(gaussian_peak_blur(torch.zeros(1, 1, 9, 9).index_put_((torch.tensor([0]),) * 2 + (torch.tensor([4]),) * 2, torch.tensor([1.0])), 1.5).max()) == pytest.approx(1.0)  # fmt: skip


def test_the_vote_loss_is_smallest_for_the_perfect_output_and_counts_offsets_on_parts_only() -> None:
    instance, centres = _two_parts()
    targets = vote_targets(instance, centres, np.array([[True, True]]))
    dense = dense_vote_targets(torch.from_numpy(targets.ids), targets.tables)
    perfect = _perfect_raw(dense)
    best = vote_loss(perfect, dense)
    assert float(best) < 1e-3
    off = perfect.clone()
    off[:, 1] += 0.5  # every dx half the part's size off: L1 0.5 in one of the two offsets
    assert float(vote_loss(off, dense)) == pytest.approx(float(best) + 0.25, abs=1e-4)
    background_only = perfect.clone()
    background_only[:, 1:, dense[0, 0] == 0] = 5.0  # offsets where nothing votes are not judged
    assert float(vote_loss(background_only, dense)) == pytest.approx(float(best), abs=1e-6)


def _blob_and_votes(H: int = 48, W: int = 64):
    """A centre target with one blob at (40.3, 17.6) and the votes of a part whose pixels lie 6-14 px from it."""
    cx, cy = 40.3, 17.6
    u = torch.arange(W) + 0.5
    v = torch.arange(H) + 0.5
    center = torch.exp(-((u - cx) ** 2)[None, :] / 18 - ((v - cy) ** 2)[:, None] / 18)[None, None]
    instance = torch.full((1, H, W), -1, dtype=torch.int64)
    instance[0, 22:32, 30:52] = 0
    targets = vote_targets(instance, np.array([[[cx, cy]]]), np.array([[True]]))
    votes = dense_vote_targets(torch.from_numpy(targets.ids), targets.tables)
    return center, votes


def _voted_centre(votes: torch.Tensor) -> torch.Tensor:
    """Where the voting pixels (fg near 1, away from the zoom's blurred rim) point, ``(N, 2)`` continuous x, y."""
    fg = votes[0, 0] > 0.999
    v, u = torch.nonzero(fg, as_tuple=True)
    return torch.stack([u + 0.5 + votes[0, 1][fg], v + 0.5 + votes[0, 2][fg]], dim=1)


@pytest.mark.parametrize("field", ["hflip_p", "vflip_p", "scale"])
def test_geometric_augmentations_keep_the_votes_pointing_at_the_moved_blob(field) -> None:
    center, votes = _blob_and_votes()
    image = torch.rand(1, 3, *center.shape[-2:])
    off = AugmentConfig.none()
    change = {"scale": (1.2, 1.2)} if field == "scale" else {field: 1.0}
    config = AugmentConfig(**{**off.__dict__, **change})
    gen = torch.Generator().manual_seed(5)
    img, ctr, curv, vot = augment_with_votes(image, center, center[:, 0], votes, config, gen)
    # the same draws as without votes: image and centres bit for bit augment()'s
    i2, c2, k2 = augment(image, center, center[:, 0], config, torch.Generator().manual_seed(5))
    assert torch.equal(img, i2) and torch.equal(ctr, c2) and torch.equal(curv, k2)
    peak = torch.nonzero(ctr[0, 0] == ctr[0, 0].max())[0]  # (v, u) of the moved blob's peak pixel
    pointed = _voted_centre(vot)
    assert len(pointed) > 50
    assert torch.allclose(pointed.mean(0), torch.tensor([peak[1] + 0.5, peak[0] + 0.5]).float(), atol=0.75)
    assert float((pointed - pointed.mean(0)).norm(dim=1).max()) < 0.75  # every voting pixel agrees
    if field == "scale":  # the area grows with the zoom's square
        fg = vot[0, 0] > 0.999
        assert torch.allclose(vot[0, 3][fg], votes[0, 3][votes[0, 0] > 0][0] + 2 * np.log(1.2), atol=1e-4)


def test_augment_with_votes_refuses_votes_of_another_shape() -> None:
    image = torch.rand(2, 3, 8, 10)
    with pytest.raises(ValueError, match="votes must be"):
        augment_with_votes(
            image, image[:, :1], image[:, 0], torch.zeros(2, 3, 8, 10), AugmentConfig(), torch.Generator()
        )


def test_a_vote_network_started_from_weights_without_votes_computes_their_maps_then_follows_its_votes() -> None:
    torch.manual_seed(4)
    for base, name in ((UNetSpec.dimo_context(), "dimo-votes"), (UNetSpec.tless_factored(5), "tless-votes")):
        spec = UNetSpec.named(name, center_channels=base.center_channels)
        assert spec.center_votes and UNetSpec.from_dict(spec.as_dict()) == spec
        old = base.as_dict()
        assert UNetSpec.from_dict(old) == base  # written before the field: no votes
        before = UNet(base).eval()
        voting = UNet(spec).eval()
        missing, unexpected = voting.load_state_dict(before.state_dict(), strict=False)
        assert not unexpected and missing and all(k.startswith("vote_head.") for k in missing)
        image = torch.rand(2, 3, 54, 72)  # not a multiple of T-LESS's stride 12: padded and cropped back
        with torch.no_grad():
            c0, k0 = before.probabilities(image)
            c1, k1 = voting.probabilities(image)
            _, _, votes = voting.forward_outputs(image)
            assert votes.shape == (2, 4, 54, 72)
            assert torch.allclose(c0, c1, atol=1e-6) and torch.equal(k0, k1)  # fg starts at sigmoid(-4): no vote
            # every pixel now votes for itself with an area of 1 pixel: the map is 1 everywhere
            last = voting.vote_head.body[-1]
            torch.nn.init.zeros_(last.weight)
            last.bias.copy_(torch.tensor([10.0, 0.0, 0.0, -LOG_AREA_MEAN / LOG_AREA_SCALE]))
            c2, k2 = voting.probabilities(image)
        assert torch.equal(k2, k0)
        agnostic = c2.sum(1)  # a factored network's channels sum to its class-agnostic map
        assert float(agnostic.min()) > 0.999 and float(agnostic.max()) <= 1.0 + 1e-5
        assert float(c0.sum(1).max()) < 0.5  # the head's own map was low (its bias starts at -4)


def test_samples_carry_their_vote_targets_through_the_cache(tmp_path) -> None:
    root = method_data.build(tmp_path / "dimo", n_scenes=1)
    ds = open_dimo(root, "real")
    meshes = MeshCache(ds.models)
    config = TargetConfig.for_dataset("dimo")
    fresh = load_samples(ds, config, meshes, tmp_path / "cache", votes=True, progress=False)
    cached = load_samples(ds, config, meshes, tmp_path / "cache", votes=True, progress=False)
    plain = load_samples(ds, config, meshes, tmp_path / "cache", progress=False)
    assert plain.vote_ids is None and fresh.vote_ids is not None
    assert np.array_equal(fresh.vote_ids, cached.vote_ids)
    assert all(np.array_equal(a, b) for a, b in zip(fresh.vote_tables, cached.vote_tables, strict=True))
    with pytest.raises(ValueError, match="without their vote targets"):
        plain.vote_batch([0])
    dense = fresh.vote_batch([0, 1])
    assert dense.shape == (2, 4, method_data.HEIGHT, method_data.WIDTH)
    # the voting pixels are the visible target parts of each view, each pointing at its centre blob's peak
    scene = ds.scene(ds.scene_keys[0])
    maps, votes = scene_targets_with_votes(scene, ds.models, meshes, config)
    assert torch.equal(maps.center, scene_targets(scene, ds.models, meshes, config).center)
    for i in range(2):
        pointed = _voted_centre(dense[i : i + 1])
        assert len(pointed) > 20
        blob = maps.center[i, 0]
        u = (pointed[:, 0] - 0.5).round().long().clamp(0, blob.shape[1] - 1)
        v = (pointed[:, 1] - 0.5).round().long().clamp(0, blob.shape[0] - 1)
        assert float(blob[v, u].min()) > 0.85  # every vote lands on the peak of a centre blob
    assert np.array_equal(votes.ids[:2], fresh.vote_ids[:2])


def test_a_vote_map_ignores_non_finite_votes_and_a_spec_refuses_a_non_finite_blur() -> None:
    raw = torch.zeros(1, 4, 12, 16)
    raw[:, 0] = 10.0  # every pixel votes for itself, area 1
    raw[:, 3] = -LOG_AREA_MEAN / LOG_AREA_SCALE
    raw[0, 1, 3, 4] = float("nan")
    raw[0, 2, 5, 6] = float("inf")
    voted = vote_map(raw, sigma_px=1.0)
    assert torch.isfinite(voted).all() and float(voted.min()) > 0.99
    with pytest.raises(ValueError, match="vote sigma"):
        UNetSpec(vote_sigma_px=float("inf"))
    with pytest.raises(ValueError, match="vote mix"):
        UNetSpec(vote_mix="sum")


def _dense_vote_map(raw: torch.Tensor, sigma_px: float) -> torch.Tensor:
    """The vote map computed over every pixel (what :func:`vote_map` did before it read the voting pixels only)."""
    B, _, H, W = raw.shape
    p = torch.sigmoid(raw[:, 0])
    log_area = LOG_AREA_MEAN + LOG_AREA_SCALE * raw[:, 3].clamp(-6.0, 6.0)
    weight = torch.where(p >= 0.5, p * torch.exp(-log_area), torch.zeros_like(p))
    size = torch.exp(0.5 * log_area)
    gx = torch.arange(W, dtype=torch.float32) + raw[:, 1] * size
    gy = torch.arange(H, dtype=torch.float32)[:, None] + raw[:, 2] * size
    out = torch.zeros(B * H * W)
    base = (torch.arange(B) * (H * W))[:, None, None]
    x0, y0 = torch.floor(gx), torch.floor(gy)
    fx, fy = gx - x0, gy - y0
    for ox, oy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        xi, yi = x0.long() + ox, y0.long() + oy
        inside = (xi >= 0) & (xi < W) & (yi >= 0) & (yi < H) & (weight > 0) & torch.isfinite(gx) & torch.isfinite(gy)
        out.index_add_(0, (base + yi.clamp(0, H - 1) * W + xi.clamp(0, W - 1))[inside], (weight * w)[inside])
    return gaussian_peak_blur(out.view(B, 1, H, W), sigma_px).clamp_(0.0, 1.0)


def test_a_vote_map_reads_only_the_voting_pixels_and_equals_the_dense_computation() -> None:
    generator = torch.Generator().manual_seed(5)
    raw = torch.randn(3, 4, 30, 40, generator=generator) * 2.0
    raw[2, 0] = -3.0  # a view where nobody votes
    raw[0, 1, 3, 4] = float("nan")
    raw[0, 2, 5, 6] = float("inf")
    raw[1, 1, 7, 8] = 1e30  # a finite vote far outside the view
    raw[1, 2, 9, 9] = -1e30
    voted = vote_map(raw, sigma_px=1.5)
    assert torch.equal(voted, _dense_vote_map(raw, 1.5))
    assert float(voted[2].abs().max()) == 0.0 and float(voted[:2].max()) > 0.0
    assert torch.equal(vote_map(torch.full((1, 4, 5, 6), -5.0), 1.0), torch.zeros(1, 1, 5, 6))


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--dataset", "tless", "--variant", "tless-lean", "--center-votes"], "--center-votes: votes make one"),
        (["--dataset", "dimo", "--variant", "tless-factored"], "--variant: tless-factored cannot be built"),
        (["--dataset", "dimo", "--factored-centers"], "--factored-centers: needs one center channel per object"),
    ],
)
def test_train_refuses_a_network_that_does_not_fit_the_data_before_reading_it(tmp_path, capsys, flags, message) -> None:
    """Votes on independent per-object channels, a factored variant on DIMO's one channel: one line, nothing
    written, before any data is resolved (``network_spec_of`` is the one check, for the CLI and ``TrainConfig``)."""
    from bop_cender.cli import main

    code = main(["train", *flags, "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert code == 2 and not (tmp_path / "r").exists()
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
