"""The scene polish's windowed cost (``pose/scene_polish.py``): it ranks poses as the full scene cost does, its
compiled pass gives the torch steps' costs, and its windows drop the target edges along their inner sides. The
polish itself: ``test_polish.py``."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).parents[1]))
from method_data import BOX_T_B, full_scene_cost, perturb, target_parts  # noqa: E402

from bop_cender.pose.backend import backend_named  # noqa: E402
from bop_cender.pose.scene_polish import scene_window  # noqa: E402
from bop_cender.render.rasterizer import render_scene  # noqa: E402

EDGE_THRESHOLD = BOX_T_B  # the fixture's curvature scale is 1
#: The default backend's scene cost (:meth:`~bop_cender.pose.backend.Backend.scene_cost`).
scene_cost = backend_named("auto").scene_cost


def test_window_cost_ranks_poses_as_thefull_scene_cost(mini):
    ds, scene, meshes, maps, cams, dist = mini
    edges = maps.curvature > BOX_T_B
    parts = target_parts(ds, scene)
    moving, other = sorted(parts)
    trials = np.stack([parts[moving]] + [perturb(parts[moving], a, s) for a, s in ((1, 0.5), (3, 1), (6, 2), (10, 4))])
    window = scene_window(meshes(moving), parts[moving], [(meshes(other), parts[other])], cams.Ks, cams.T_cam_world,
                          edges, dist, EDGE_THRESHOLD, margin_px=12)  # fmt: skip
    h, w = window.size
    assert h <= cams.height and w <= cams.width and window.other_depth.shape == (len(cams.Ks), h, w)
    windowed = backend_named("auto").window_costs(window, trials)
    full = np.array([full_scene_cost(meshes, {**parts, moving: T}, cams, edges, dist) for T in trials])
    assert np.all(np.diff(windowed) > 0), windowed  # the truth first, then growing with the perturbation
    assert np.all(np.diff(full) > 0), full
    assert np.corrcoef(windowed, full)[0, 1] > 0.95


def test_the_compiled_window_cost_gives_the_torch_costs(mini):
    """The CPU's compiled pass after the render (composite, curvature, forward, own edges) gives the torch steps'
    costs: near the truth, far from it, a pose that leaves the windows (no own edge: the window's diagonal) and a
    window without target edges (no backward term); the own-edge binarisation sees the same float32 curvature, so
    a clean silhouette step (curvature 3.0, the default threshold) falls on the same side."""
    from bop_cender.pose.scene_polish import SceneWindow, torch_window_costs, window_poses
    from bop_cender.pose.window_kernel import window_costs

    auto, numba = backend_named("auto"), backend_named("numba")

    def steps(window, trials):  # the torch steps after the numba backend's render (the same maps as torch's)
        m, (h, w) = len(trials), window.size
        render = render_scene(
            [window.mesh], window_poses(window, trials), window.K.repeat(m, 1, 1), h, w, backend=numba
        )
        return torch_window_costs(window, render.depth, render.normals, m)

    ds, scene, meshes, maps, cams, dist = mini
    edges = maps.curvature > BOX_T_B
    parts = target_parts(ds, scene)
    moving, other = sorted(parts)
    trials = np.stack([parts[moving]] + [perturb(parts[moving], a, s) for a, s in ((1, 0.5), (6, 2), (25, 15))])
    gone = parts[moving].copy()
    gone[:3, 3] += 1000.0 * cams.T_cam_world[0, 2, :3]  # a metre further from the first camera: out of its window
    trials = np.concatenate([trials, gone[None]])
    for threshold in (EDGE_THRESHOLD, 3.0):
        window = scene_window(meshes(moving), parts[moving], [(meshes(other), parts[other])], cams.Ks,
                              cams.T_cam_world, edges, dist, threshold, margin_px=12)  # fmt: skip
        np.testing.assert_allclose(numba.window_costs(window, trials), steps(window, trials), rtol=1e-5)
        no_targets = SceneWindow(**{**window.__dict__, "target_edges": torch.zeros_like(window.target_edges)})
        np.testing.assert_allclose(numba.window_costs(no_targets, trials), steps(no_targets, trials), rtol=1e-5)
    assert auto.window_costs(window, trials[:1]).tolist() == numba.window_costs(window, trials[:1]).tolist()
    V, (h, w) = len(cams.Ks), window.size
    blank = torch.zeros((V, h, w))
    only_background = window_costs(blank, torch.zeros((V, h, w, 3)), blank, torch.zeros((V, h, w, 3)), dist,
                                   window.offsets, torch.ones((V, h, w), dtype=torch.bool), 3.0)  # fmt: skip
    diagonal = np.hypot(cams.height, cams.width) + np.float32(np.hypot(h, w))  # nothing drawn: both terms at most
    np.testing.assert_allclose(only_background.numpy(), np.full(V, diagonal), rtol=1e-6)


def test_the_compiled_scene_cost_gives_the_torch_cost(mini):
    """The full scene cost with its post-render steps compiled (the CPU's default) equals the torch steps', for the
    truth, a perturbed part and a part that has left every view."""
    ds, scene, meshes, maps, cams, dist = mini
    edges = maps.curvature > BOX_T_B
    parts = target_parts(ds, scene)
    ids = sorted(parts)
    Ks = torch.as_tensor(cams.Ks, dtype=torch.float32)
    away = parts[ids[1]].copy()
    away[:3, 3] += 1e5
    for poses in (parts, {**parts, ids[1]: perturb(parts[ids[1]], 6, 3)}, {**parts, ids[1]: away}):
        T_cm = np.einsum("vij,mjk->vmik", cams.T_cam_world, np.stack([poses[i] for i in ids]))
        args = ([meshes(i) for i in ids], torch.as_tensor(T_cm, dtype=torch.float32), Ks, edges, dist, 3.0)
        compiled, torch_steps = backend_named("numba").scene_cost(*args), backend_named("torch").scene_cost(*args)
        assert compiled == pytest.approx(torch_steps, rel=1e-5) and scene_cost(*args) == compiled


def test_window_drops_target_edges_along_its_inner_sides_only():
    """Target edges within WINDOW_BORDER_PX of a window side inside the image are left out (a neighbour's edges
    spilling across it); a side on the image border keeps its edges."""
    from bop_cender.pose.scene_polish import WINDOW_BORDER_PX, _inside_border

    top, left = torch.tensor([0, 10, 40]), torch.tensor([5, 0, 60])  # view 2's window ends on the image's corner
    keep = _inside_border(top, left, (20, 20), (60, 80), WINDOW_BORDER_PX)
    b = WINDOW_BORDER_PX
    assert keep.shape == (3, 20, 20)
    # view 0: the top side is the image's top (kept); left, right, bottom inside the image (dropped)
    assert keep[0, 0, b:-b].all() and not keep[0, -b:].any() and not keep[0, :, :b].any() and not keep[0, :, -b:].any()
    # view 1: the left side is the image's left (kept)
    assert keep[1, b:-b, 0].all() and not keep[1, :b].any() and not keep[1, :, -b:].any()
    # view 2: bottom and right sides are the image's (kept)
    assert keep[2, -1, b:].all() and keep[2, b:, -1].all() and not keep[2, :b].any() and not keep[2, :, :b].any()
    assert keep[:, b:-b, b:-b].all()


def test_scene_window_drops_the_border_rows_in_a_real_window(mini):
    ds, scene, meshes, maps, cams, dist = mini
    parts = target_parts(ds, scene)
    moving, other = sorted(parts)
    everywhere = torch.ones_like(maps.curvature, dtype=torch.bool)
    window = scene_window(meshes(moving), parts[moving], [(meshes(other), parts[other])], cams.Ks, cams.T_cam_world,
                          everywhere, dist, EDGE_THRESHOLD, margin_px=12)  # fmt: skip
    h, w = window.size
    inner = (window.offsets[:, 0] > 0) & (window.offsets[:, 0] + h < cams.height)
    assert inner.any()  # a window with its top and bottom sides inside the image drops their rows
    assert not window.target_edges[inner][:, 0].any() and not window.target_edges[inner][:, -1].any()
    assert window.target_edges[inner][:, h // 2, w // 2].all()
    sides = (window.offsets[:, 1] > 0) & (window.offsets[:, 1] + w < cams.width)
    assert sides.any()
    assert not window.target_edges[sides][:, :, 0].any() and not window.target_edges[sides][:, :, -1].any()
