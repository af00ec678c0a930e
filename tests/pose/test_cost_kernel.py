"""The compiled candidate cost (the numba backend's on the CPU, and ``auto``'s) against the torch atlases.

Same windows, occlusion rule and curvature; the sums are float64 in the compiled loop and float32 in torch's
own order, so the costs agree to float32 rounding: candidates inside the images, cut by the border, out of
every view, behind placed objects (hidden pixels and the 0.5 mm contact margin), threads.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import trimesh

from bop_cender.pose.backend import NumbaBackend, backend_named
from bop_cender.render.mesh import prepare_mesh

try:
    from tests.pose.test_cost import H, W, rig, target
    from tests.render.reference import bracket, holed_plate, pose
except ImportError:  # pytest's default import mode puts each test folder on sys.path
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "render"))
    from reference import bracket, holed_plate, pose
    from test_cost import H, W, rig, target

AUTO, NUMBA, TORCH = backend_named("auto"), backend_named("numba"), backend_named("torch")


def _candidates(n: int, seed: int) -> np.ndarray:
    """``(n, 4, 4)`` world poses: random rotations near the origin, the last two cut by a border and out of view."""
    rng = np.random.default_rng(seed)
    T_wm = np.stack([pose(tuple(rng.uniform(-180, 180, 3)), tuple(rng.uniform(-12, 12, 3))) for _ in range(n)])
    T_wm[-2, :3, 3] += [-90, 40, 0]
    T_wm[-1, :3, 3] += [1500, 1500, 1500]  # in front of every camera, outside every image
    return T_wm


@pytest.mark.parametrize(
    "make",
    [lambda: bracket(16), holed_plate, lambda: trimesh.creation.box((40.0, 30.0, 20.0))],
    ids=["bracket", "holed plate", "12-face box (6 face bits)"],
)
def test_compiled_costs_agree_with_the_torch_atlases(make) -> None:
    mesh = prepare_mesh(make())
    T_cw, Ks = rig()
    dist = target(mesh, T_cw, Ks)
    weights = torch.tensor([1.0, 0.7, 1.3])
    T = torch.as_tensor(np.einsum("vij,bjk->bvik", T_cw, _candidates(12, seed=4)), dtype=torch.float32)
    occ = torch.zeros((3, H, W))
    occ[:, 30:70, 40:90] = 300.0  # a placed object's face through the middle of the rig's views
    occ[1, 40:60, 50:70] = 305.0  # ... and a patch 5 mm further back in view 1
    for occluder in (None, occ):
        torch_costs = TORCH.candidate_costs(mesh, T, Ks, H, W, dist, weights, occluder_depth=occluder)
        compiled = NUMBA.candidate_costs(mesh, T, Ks, H, W, dist, weights, occluder_depth=occluder)
        assert compiled.dtype == torch.float32 and compiled.shape == (12,)
        torch.testing.assert_close(compiled, torch_costs, rtol=2e-6, atol=1e-5)
        assert compiled[-1] == pytest.approx(float(weights.sum()) * math.hypot(H, W), rel=1e-6)  # nothing in view
    assert AUTO.candidate_costs(mesh, T, Ks, H, W, dist, weights).equal(  # the CPU's default
        NUMBA.candidate_costs(mesh, T, Ks, H, W, dist, weights)
    )


def test_threads_give_the_serial_costs(on_one_and_two_threads) -> None:
    mesh = prepare_mesh(bracket(16))
    T_cw, Ks = rig()
    dist = target(mesh, T_cw, Ks)
    T = torch.as_tensor(np.einsum("vij,bjk->bvik", T_cw, _candidates(9, seed=8)), dtype=torch.float32)
    serial, threaded = on_one_and_two_threads(lambda: AUTO.candidate_costs(mesh, T, Ks, H, W, dist, np.ones(3)))
    assert torch.equal(serial, threaded)


def test_a_candidate_behind_the_near_plane_is_left_to_the_torch_pipeline() -> None:
    """The compiled loop does not clip at the near plane: a call with a vertex behind it takes the torch atlases in
    every backend, the numba backend with one warning."""
    mesh = prepare_mesh(bracket(16))
    T_cw, Ks = rig()
    dist = target(mesh, T_cw, Ks)
    T_wm = _candidates(3, seed=2)
    T_wm[0, :3, 3] = [0.0, 0.0, -299.5]  # the first camera sits at world z = -300: inside the part
    T = torch.as_tensor(np.einsum("vij,bjk->bvik", T_cw, T_wm), dtype=torch.float32)
    default = AUTO.candidate_costs(mesh, T, Ks, H, W, dist, np.ones(3))
    assert torch.equal(default, TORCH.candidate_costs(mesh, T, Ks, H, W, dist, np.ones(3)))
    with pytest.warns(RuntimeWarning, match="the compiled render cost leaves geometry behind the near plane"):
        assert torch.equal(default, NumbaBackend(insist=True).candidate_costs(mesh, T, Ks, H, W, dist, np.ones(3)))
