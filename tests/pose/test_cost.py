"""The render-and-compare cost: distance maps, the per-view formula, and the end-to-end path."""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy import ndimage

from bop_cender.pose.backend import backend_named
from bop_cender.pose.cost import distance_map, distance_maps, render_cost
from bop_cender.render.curvature import curvature
from bop_cender.render.mesh import prepare_mesh
from bop_cender.render.rasterizer import render_candidates, render_scene

#: The default backend's render cost (:meth:`~bop_cender.pose.backend.Backend.candidate_costs`).
candidate_costs = backend_named("auto").candidate_costs

try:
    from tests.render.reference import K_matrix, bracket, pose
except ImportError:  # pytest's default import mode puts each test folder on sys.path
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "render"))
    from reference import K_matrix, bracket, pose

H, W = 96, 128

# The `device` fixture (CPU, and CUDA where present) is in tests/conftest.py.


def rig() -> tuple[np.ndarray, np.ndarray]:
    """Three views ``T_cam_world (3, 4, 4)`` around the origin at 300 mm and their ``K (3, 3, 3)``."""
    views = [pose((0, 0, 0), (0, 0, 300)), pose((0, 50, 0), (0, 0, 300)), pose((-40, 0, 20), (0, 0, 300))]
    Ks = np.stack([K_matrix(260.0, 260.0, 64.2, 47.9), K_matrix(240.0, 240.0, 63.1, 48.4), K_matrix(250, 250, 64, 48)])
    return np.stack(views), Ks


def target(mesh, T_cam_world: np.ndarray, Ks: np.ndarray) -> torch.Tensor:
    """Distance maps of the render at the true pose (curvature >= 1 is an edge)."""
    views = [render_scene([mesh], T_cam_world[v][None, None], Ks[v][None], H, W).normals[0] for v in range(3)]
    return torch.as_tensor(distance_maps((curvature(torch.stack(views)) >= 1.0).numpy()))


def test_distance_map_is_the_exact_euclidean_distance() -> None:
    rng = np.random.default_rng(0)
    edges = rng.random((40, 50)) < 0.02
    expected = ndimage.distance_transform_edt(~edges)
    assert np.abs(distance_map(edges) - expected).max() < 1e-4
    assert distance_map(edges).dtype == np.float32
    as_torch = distance_map(torch.as_tensor(edges))
    assert isinstance(as_torch, torch.Tensor) and torch.allclose(as_torch, torch.as_tensor(expected).float())
    assert np.allclose(distance_map(np.zeros((30, 40), bool)), 50.0)  # no edge at all: the image diagonal
    stacked = distance_maps(np.stack([edges, edges]))
    assert stacked.shape == (2, 40, 50) and np.array_equal(stacked[1], distance_map(edges))
    first = distance_map(edges)
    for size in range(1, 7):  # the same bits whatever the allocator hands out
        _ = np.empty(size * 24, dtype=np.uint8)
        assert np.array_equal(distance_map(edges), first)


def test_render_cost_is_the_curvature_weighted_mean_distance() -> None:
    dist = torch.arange(2 * 6 * 8, dtype=torch.float32).view(2, 6, 8)
    curv = torch.zeros(1, 2, 3, 3)
    curv[0, 0, 1, 1], curv[0, 0, 2, 2] = 1.0, 3.0  # view 0: pixels (2, 3) and (3, 4) of the image
    curv[0, 1, 0, 0] = 2.0  # view 1: window pixel (0, 0) at image (-1, 5): outside, does not count
    curv[0, 1, 1, 1] = 0.5  # image pixel (0, 6)
    offsets = torch.tensor([[[1, 2], [-1, 5]]])
    weights = torch.tensor([2.0, 0.5])
    d0 = (1 * dist[0, 2, 3] + 3 * dist[0, 3, 4]) / 4
    d1 = dist[1, 0, 6]
    cost = render_cost(curv, dist, offsets, weights)
    assert torch.allclose(cost, torch.stack([2.0 * d0 + 0.5 * d1]))
    empty = render_cost(torch.zeros(1, 2, 3, 3), dist, offsets, weights)  # no curvature: the diagonal
    assert torch.allclose(empty, torch.tensor([2.5 * math.hypot(6, 8)]))
    assert torch.isfinite(empty).all()


def test_candidate_costs_equal_the_window_and_full_frame_costs(device) -> None:
    mesh = prepare_mesh(bracket(16), device=device)
    T_cw, Ks = rig()
    dist = target(mesh.to("cpu"), T_cw, Ks).to(device)
    weights = torch.tensor([1.0, 0.7, 1.3], device=device)
    rng = np.random.default_rng(1)
    T_wm = np.stack([pose(tuple(rng.uniform(-180, 180, 3)), tuple(rng.uniform(-10, 10, 3))) for _ in range(6)])
    T_wm[:, :3, 3] += [[0, 0, 0]] * 3 + [[-90, 40, 0], [500, 0, 0], [0, 0, 0]]  # 3: cut by borders, 4: gone
    T = torch.as_tensor(np.einsum("vij,bjk->bvik", T_cw, T_wm), device=device)
    costs = candidate_costs(mesh, T, Ks, H, W, dist, weights)
    assert costs.shape == (6,) and torch.isfinite(costs).all()
    windows = render_candidates(mesh, T, Ks, H, W)
    windowed = render_cost(curvature(windows.normals), dist, windows.offsets, weights)
    assert torch.allclose(costs, windowed, rtol=1e-4, atol=1e-3)
    for b in (0, 1):  # fully inside the images: the same as the full-frame definition
        full = render_scene([mesh], T[b][:, None], Ks, H, W)
        border = full.mask[:, [0, -1]].any() or full.mask[:, :, [0, -1]].any()
        assert not border  # (candidate 2 touches the border: there 'reflect' and windows differ slightly)
        curv = curvature(full.normals)
        per_view = (curv * dist).sum((1, 2)) / curv.sum((1, 2))
        assert torch.allclose(costs[b], (per_view * weights).sum(), rtol=1e-4)
    atlases = backend_named("torch").candidate_costs  # the torch atlases: the CPU's default is compiled
    for b in range(6):  # chunking and order do not matter
        one = atlases(mesh, T[b : b + 1], Ks, H, W, dist, weights, chunk_pixels=4096)
        assert torch.allclose(one, costs[b : b + 1], rtol=1e-5)
    small_chunks = atlases(mesh, T, Ks, H, W, dist, weights, chunk_pixels=8192)
    threaded = atlases(mesh, T, Ks, H, W, dist, weights, chunk_pixels=8192, workers=2)
    if device.type == "cpu":  # the chunks' threads give the same bits
        assert torch.equal(small_chunks, threaded)
    else:  # one stream (workers ignored); CUDA's atomic sums may order differently from call to call
        torch.testing.assert_close(small_chunks, threaded, rtol=1e-6, atol=1e-5)
    worst = weights.sum() * math.hypot(H, W)  # every view costs the image diagonal
    assert torch.isclose(costs[4], worst) and costs[3] < 0.5 * worst


def test_cost_is_lowest_at_the_true_pose_and_grows_with_the_error() -> None:
    mesh = prepare_mesh(bracket(16))
    T_cw, Ks = rig()
    dist = target(mesh, T_cw, Ks)
    steps = [0.0, 2.0, 5.0, 10.0, 20.0]  # degrees and mm together
    T_wm = np.stack([pose((s, -0.5 * s, 0.3 * s), (s, 0.5 * s, -0.5 * s)) for s in steps])
    costs = candidate_costs(mesh, np.einsum("vij,bjk->bvik", T_cw, T_wm), Ks, H, W, dist, np.ones(3))
    assert costs[0] < 0.05
    assert bool((costs[1:] > costs[:-1]).all()), costs
