"""PatchMaps: mostly-zero center targets kept as patches give back the dense bytes exactly."""

from __future__ import annotations

import numpy as np
import pytest

from bop_cender.net.patch_maps import PatchMaps


def _maps(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    maps = []
    for _ in range(n):
        m = np.zeros((4, 20, 30), np.uint8)
        for _ in range(rng.integers(0, 4)):  # some samples have no blob at all
            c, y, x = rng.integers(0, 4), rng.integers(0, 18), rng.integers(0, 27)
            m[c, y : y + 3, x : x + rng.integers(1, 4)] = rng.integers(1, 256, size=(min(3, 20 - y), 1))
        maps.append(m)
    return maps


def test_patches_give_back_the_dense_maps_bit_for_bit() -> None:
    rng = np.random.default_rng(0)
    maps = _maps(rng, 12)
    dense = np.stack(maps)
    patched = PatchMaps.from_dense(maps)
    assert len(patched) == 12 and patched.shape == dense.shape
    assert np.array_equal(patched.dense(range(12)), dense)
    order = rng.permutation(12)[:5]
    assert np.array_equal(patched.dense(order), dense[order])
    assert patched.nbytes < dense.nbytes / 4
    whole = PatchMaps.concat([PatchMaps.from_dense(maps[:5]), PatchMaps.from_dense(maps[5:])])
    assert np.array_equal(whole.dense(np.arange(12)[::-1]), dense[::-1])


def test_an_all_zero_set_and_bad_input() -> None:
    zeros = [np.zeros((2, 5, 6), np.uint8)] * 3
    patched = PatchMaps.from_dense(zeros)
    assert patched.boxes.shape == (0, 6) and np.array_equal(patched.dense([2, 0]), np.zeros((2, 2, 5, 6), np.uint8))
    with pytest.raises(IndexError, match="sample 3 of 3"):
        patched.dense([3])
    with pytest.raises(ValueError, match="map 1 is"):
        PatchMaps.from_dense([np.zeros((2, 5, 6), np.uint8), np.zeros((2, 5, 7), np.uint8)])
    with pytest.raises(ValueError, match="not uint8"):
        PatchMaps.from_dense([np.full((1, 5, 6), 0.6)])  # a float map would be truncated to zeros
    with pytest.raises(ValueError, match="sorted by sample"):
        PatchMaps((2, 1, 5, 6), np.array([[1, 0, 0, 0, 1, 1], [0, 0, 0, 0, 1, 1]]), np.ones(2, np.uint8))
    with pytest.raises(ValueError, match="inside"):
        PatchMaps((1, 1, 5, 6), np.array([[0, 0, 4, 0, 2, 1]]), np.ones(2, np.uint8))
    empty_scene = PatchMaps.from_dense(np.zeros((0, 2, 5, 6), np.uint8))  # a scene without views adds nothing
    assert len(PatchMaps.concat([empty_scene, patched])) == 3
    with pytest.raises(ValueError, match="different sizes"):
        PatchMaps.concat([patched, PatchMaps.from_dense([np.zeros((1, 5, 6), np.uint8)])])
