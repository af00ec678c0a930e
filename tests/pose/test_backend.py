"""One backend object per name runs stage 3's five computations (``bop_cender.pose.backend``); a run names it once.

The ``torch`` and ``numba`` backends compute the same renders and costs, to float32 rounding (the render bit for bit
on the CPU); ``auto`` is ``numba`` where numba runs, which on this CPU is everywhere; the setting ``poses.backend``
takes only the three names and is what ``--set`` and the sidecar see.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).parents[1]))
from method_data import BOX_T_B, gt_of, perturb  # noqa: E402

from bop_cender.errors import ConfigError  # noqa: E402
from bop_cender.method import CenDerNetConfig  # noqa: E402
from bop_cender.pose.backend import Backend, NumbaBackend, TorchBackend, backend_named  # noqa: E402
from bop_cender.pose.config import PoseConfig  # noqa: E402
from bop_cender.pose.edge_model import edge_model_of  # noqa: E402
from bop_cender.pose.scene_polish import scene_window  # noqa: E402
from bop_cender.render.backend import BACKEND_NAMES, render_backend_named  # noqa: E402
from bop_cender.render.rasterizer import render_scene  # noqa: E402


def test_each_name_is_one_object_per_process_and_an_unknown_name_is_refused() -> None:
    assert BACKEND_NAMES == ("auto", "torch", "numba")
    for name in BACKEND_NAMES:
        backend = backend_named(name)
        assert isinstance(backend, Backend) and backend.name == name and backend is backend_named(name)
        assert render_backend_named(name).name == name
    assert isinstance(backend_named("torch"), TorchBackend)
    assert isinstance(backend_named("auto"), NumbaBackend) and not backend_named("auto").insist
    assert backend_named("numba").insist
    for named in (backend_named, render_backend_named):
        with pytest.raises(ValueError, match="unknown backend 'cuda'; expected one of auto, torch, numba"):
            named("cuda")


def test_the_setting_takes_the_three_names_and_reaches_the_run_config() -> None:
    assert PoseConfig().backend == "auto"
    config = CenDerNetConfig().with_settings(["poses.backend=torch"])
    assert config.poses.backend == "torch" and config.as_dict()["poses"]["backend"] == "torch"
    with pytest.raises(ConfigError, match="poses.backend: expected one of auto, torch, numba, got 'cuda'"):
        CenDerNetConfig().with_settings(["poses.backend=cuda"])
    assert CenDerNetConfig().poses.for_network_centers().backend == "auto"


def test_torch_and_numba_compute_the_same_five_things(mini) -> None:
    """The render (bit for bit), the candidates' render cost, the edge proxy, the scene cost and the windowed scene
    cost of the same inputs, by the torch backend and by the numba one (float32 rounding apart)."""
    ds, scene, meshes, maps, cams, dist = mini
    torch_backend, numba = backend_named("torch"), backend_named("numba")
    edges = maps.curvature > BOX_T_B
    parts = {g.obj_id: g.T_world_model for g in scene.gt if ds.models[g.obj_id].is_target}
    moving, other = sorted(parts)
    g = gt_of(scene, moving).T_world_model
    poses = np.stack([perturb(g, a, s) for a, s in ((0, 0), (4, 2), (15, 8))])
    T = torch.as_tensor(np.einsum("vij,njk->nvik", cams.T_cam_world, poses), dtype=torch.float32)
    K = torch.as_tensor(cams.Ks, dtype=torch.float32)
    w = torch.full((len(cams.Ks),), 1.0 / len(cams.Ks))
    T_scene = torch.as_tensor(
        np.einsum("vij,mjk->vmik", cams.T_cam_world, np.stack([parts[moving], parts[other]])), dtype=torch.float32
    )
    mesh_pair = [meshes(moving), meshes(other)]

    a, b = (render_scene(mesh_pair, T_scene, K, cams.height, cams.width, backend=x) for x in (torch_backend, numba))
    assert a.mask.any() and torch.equal(a.depth, b.depth) and torch.equal(a.normals, b.normals)
    assert torch.equal(a.packed_face, b.packed_face)

    costs = [x.candidate_costs(meshes(moving), T, K, cams.height, cams.width, dist, w) for x in (torch_backend, numba)]
    torch.testing.assert_close(costs[0], costs[1], rtol=2e-6, atol=1e-5)
    assert costs[0][0] < costs[0][2]  # the truth costs less than a pose 15 degrees off

    model = edge_model_of(meshes(moving))
    edge = [x.edge_costs(model, T, K, dist, w) for x in (torch_backend, numba)]
    torch.testing.assert_close(edge[0], edge[1], rtol=1e-5, atol=1e-4)

    scene_costs = [x.scene_cost(mesh_pair, T_scene, K, edges, dist, BOX_T_B) for x in (torch_backend, numba)]
    assert scene_costs[0] == pytest.approx(scene_costs[1], rel=1e-5)

    window = scene_window(meshes(moving), parts[moving], [(meshes(other), parts[other])], cams.Ks, cams.T_cam_world,
                          edges, dist, BOX_T_B, 12, backend=numba)  # fmt: skip
    windowed = [x.window_costs(window, poses) for x in (torch_backend, numba)]
    np.testing.assert_allclose(windowed[0], windowed[1], rtol=1e-5)
    assert np.all(np.diff(windowed[1]) > 0)  # the truth first, then growing with the perturbation
    assert backend_named("auto").window_costs(window, poses).tolist() == windowed[1].tolist()  # auto: numba here
