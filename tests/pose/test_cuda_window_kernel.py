"""The scene polish's CUDA kernel (``bop_cender.pose.cuda_window_kernel``): the CPU's windowed costs, one launch a call.

Without a GPU the kernel runs in numba's CUDA simulator (a subprocess with ``NUMBA_ENABLE_CUDASIM=1``: every CUDA
thread a Python thread, the shared device functions the plain Python ones), where it must give the CPU's costs
(the numba backend's window costs, the compiled render and :mod:`~bop_cender.pose.window_kernel`, whose distance functions it
shares) to float64 rounding: near
the truth and far from it, a pose out of the windows (no own edge), behind a camera (None: the torch steps), with
and without the other part, with and without target edges, at two edge thresholds (3.0 is exactly the curvature of
a clean silhouette step); and the full scene cost (every part in the full frames). On a GPU (``-m cuda``)
the ``auto`` backend's window costs and scene cost take it.
"""

from __future__ import annotations

import sys
import textwrap
import types
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).parents[1]))
from method_data import BOX_T_B, perturb  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))
from cuda_simulator import simulated_ok_lines  # noqa: E402

#: What the simulated run checks, printed line by line ("ok ...") for the test to read.
_SIMULATED = textwrap.dedent(
    """
    import sys, tempfile
    from pathlib import Path
    sys.path[:0] = [{tests!r}]
    import numpy as np, torch
    import method_data
    from method_data import perturb
    from bop_cender.pose.backend import backend_named
    from bop_cender.pose.cuda_window_kernel import cuda_scene_cost, cuda_window_costs
    from bop_cender.pose.scene_polish import SceneWindow, scene_window

    ds, scene, meshes, maps, cams, dist = method_data.mini_scene(Path(tempfile.mkdtemp()) / "dimo")
    edges = maps.curvature > method_data.BOX_T_B
    Ks = np.stack([v.K for v in scene.views])
    T_cw = np.stack([v.T_cam_world for v in scene.views])
    parts = {{g.obj_id: g.T_world_model for g in scene.gt if ds.models[g.obj_id].is_target}}
    moving, other = sorted(parts)
    trials = np.stack([parts[moving]] + [perturb(parts[moving], a, s) for a, s in ((1, 0.5), (6, 2), (25, 15))])
    gone = parts[moving].copy()
    gone[:3, 3] += 1000.0 * T_cw[0, 2, :3]  # a metre further from the first camera: out of its window
    trials = np.concatenate([trials, gone[None]])
    for threshold in (method_data.BOX_T_B, 3.0):
        for others_name, others in (("other", [(meshes(other), parts[other])]), ("alone", [])):
            window = scene_window(meshes(moving), parts[moving], others, Ks, T_cw, edges, dist, threshold, 12)
            for targets_name, w in (("targets", window),
                                    ("none", SceneWindow(**{{**window.__dict__,
                                                           "target_edges": torch.zeros_like(window.target_edges)}}))):
                cpu = backend_named("numba").window_costs(w, trials)
                sim = cuda_window_costs(w, trials, threads=8)
                print("ok", threshold, others_name, targets_name, float(np.max(np.abs(sim - cpu) / cpu)), sim.tolist())
    Kt = torch.as_tensor(Ks, dtype=torch.float32)
    for name, poses in (("truth", parts), ("moved", {{**parts, moving: trials[2]}})):
        T_cm = torch.as_tensor(np.einsum("vij,mjk->vmik", T_cw, np.stack([poses[i] for i in sorted(poses)])),
                               dtype=torch.float32)
        placed = [meshes(i) for i in sorted(poses)]
        cpu = backend_named("numba").scene_cost(placed, T_cm, Kt, edges, dist, 3.0)
        sim = cuda_scene_cost(placed, T_cm, Kt, edges, dist, 3.0, threads=8)
        print("ok scene", name, abs(sim - cpu) / cpu, cpu)
    behind = parts[moving].copy()
    behind[:3, 3] -= 5000.0 * T_cw[0, 2, :3]  # behind the first camera
    print("ok near", cuda_window_costs(window, behind[None], threads=8) is None)
    print("ok empty", cuda_window_costs(window, trials[:0], threads=8).shape)
    for threads in (0, 3, 1024):
        try:
            cuda_window_costs(window, trials[:1], threads=threads)
        except ValueError as error:
            print("ok threads", threads, error)
    """
)


def test_the_kernel_gives_the_cpu_window_costs_in_numbas_cuda_simulator() -> None:
    lines = [line.split(" ", 5) for line in simulated_ok_lines(_SIMULATED)]
    costs = [line for line in lines if line[1] not in ("scene", "near", "empty", "threads")]
    assert [tuple(line[1:4]) for line in costs] == [
        (str(t), o, n) for t in (BOX_T_B, 3.0) for o in ("other", "alone") for n in ("targets", "none")
    ]
    for line in costs:
        assert float(line[4]) < 1e-9, line  # the CPU's costs but for the order of the float64 sums
        values = np.array(eval(line[5]))  # noqa: S307 (our own output)
        assert np.all(np.isfinite(values)) and values[0] < values[2] < values[3], line  # grows away from the truth
        assert values[4] == values.max(), line  # out of a window: no own edge there (its diagonal), no forward sum
    scene = [line for line in lines if line[1] == "scene"]  # the full scene cost, every part in the full frames
    assert [line[2] for line in scene] == ["truth", "moved"]
    assert all(float(line[3]) < 1e-9 for line in scene), scene
    assert float(scene[0][4]) < float(scene[1][4])
    assert [line[1:3] for line in lines if line[1] in ("near", "empty")] == [["near", "True"], ["empty", "(0,)"]]
    assert [line[2] for line in lines if line[1] == "threads"] == ["0", "3", "1024"]


def test_the_kernel_refuses_cpu_tensors_outside_the_simulator(mini) -> None:
    from bop_cender.pose.cuda_window_kernel import cuda_window_costs
    from bop_cender.pose.scene_polish import scene_window
    from bop_cender.render.cuda_loops import simulator_enabled

    if simulator_enabled():
        pytest.skip("the simulator takes CPU tensors")
    ds, scene, meshes, maps, cams, dist = mini
    T = next(g.T_world_model for g in scene.gt if ds.models[g.obj_id].is_target)
    obj = next(g.obj_id for g in scene.gt if ds.models[g.obj_id].is_target)
    window = scene_window(meshes(obj), T, [], cams.Ks, cams.T_cam_world, maps.curvature > BOX_T_B, dist, BOX_T_B, 12)
    with pytest.raises(ValueError, match="CUDA tensors"):
        cuda_window_costs(window, T[None])


def _cuda_window_stand_in():
    """An object that the backends' window costs take for a window on CUDA (only the distance maps' device and the
    views are read before the kernel is called), to test the dispatch without a GPU."""
    return types.SimpleNamespace(dist=types.SimpleNamespace(device=torch.device("cuda")), T_cam_world=np.eye(4)[None])


def test_on_cuda_the_window_costs_take_the_kernel_where_it_runs_and_else_the_torch_steps(
    monkeypatch, kernel_standing
) -> None:
    """On CUDA the ``auto`` and ``numba`` backends take the window kernel where it runs; where it declines a call (a
    vertex behind the near plane) both take the torch steps with one warning; where numba's CUDA target is missing,
    ``auto`` warns once and takes the torch steps, ``numba`` says why it cannot run (the guard's rules,
    ``tests/render/test_kernel_guard.py``)."""
    from bop_cender.pose import cuda_window_kernel
    from bop_cender.pose.backend import NumbaBackend

    auto, numba = NumbaBackend(), NumbaBackend(insist=True)
    for backend in (auto, numba):  # the torch steps, stood in for: the window has no maps to cost
        backend.torch = types.SimpleNamespace(window_costs=lambda window, T: np.full(len(T), 3.0))
    kernel_standing(cuda_window_kernel.GUARD)
    monkeypatch.setattr(cuda_window_kernel, "cuda_window_costs", lambda window, T: np.full(len(T), 7.0))
    window, T = _cuda_window_stand_in(), np.eye(4)[None]
    assert auto.window_costs(window, T).tolist() == [7.0] == numba.window_costs(window, T).tolist()
    monkeypatch.setattr(cuda_window_kernel, "cuda_window_costs", lambda window, T: None)  # declined: the near plane
    for backend in (auto, numba):
        with pytest.warns(RuntimeWarning, match="the CUDA window kernel leaves geometry behind the near plane"):
            assert backend.window_costs(window, T).tolist() == [3.0]
    kernel_standing(cuda_window_kernel.GUARD, "numba.cuda finds no CUDA driver")
    with pytest.raises(
        RuntimeError, match="needs the CUDA window kernel, which cannot run here: numba.cuda finds no CUDA driver"
    ):
        numba.window_costs(window, T)
    with pytest.warns(RuntimeWarning, match="torch steps on CUDA: numba.cuda finds no CUDA driver"):
        assert auto.window_costs(window, T).tolist() == [3.0]


def test_the_exact_keys_packed_for_cudas_atomic_maximum_follow_the_cpus_z_buffer_rule() -> None:
    """The CUDA z-buffer's exact keys (1/z's float32 bits above the face id, one int64 maximum) keep what the CPU's
    exact test keeps: the larger 1/z, ties to the larger face id, never a negative or NaN 1/z; -0.0 as +0.0."""
    from bop_cender.render.compiled_raster import keep_fragment
    from bop_cender.render.cuda_device import FACE_ID_BITS, keep_fragment_exact_simulated

    rng = np.random.default_rng(7)
    values = np.array([0.0, -0.0, 1e-3, 2e-3, 0.5, 0.5, 3.0, np.inf, -1e-3, np.nan], dtype=np.float32)
    for _ in range(500):
        cpu_key, cpu_w = np.full(1, -1, np.int64), np.full(1, -np.inf, np.float32)
        cuda_key = np.full(1, -1, np.int64)
        for q, f in zip(rng.choice(values, 6), rng.integers(0, 50, 6), strict=True):
            keep_fragment(cpu_key, cpu_w, 0, np.float32(q), np.int64(f), np.int64(f), False)
            keep_fragment_exact_simulated(cuda_key, None, 0, np.float32(q), 0, int(f), False)
        assert (cuda_key[0] & ((1 << FACE_ID_BITS) - 1) if cuda_key[0] >= 0 else -1) == cpu_key[0]


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_on_cuda_the_kernel_gives_the_cpu_costs(mini) -> None:
    """The windowed costs and the full scene cost on CUDA (the kernel, their default there) against the CPU's."""
    from bop_cender.pose.backend import backend_named
    from bop_cender.pose.scene_polish import scene_window
    from bop_cender.render.cuda_loops import cuda_unavailable_reason

    if cuda_unavailable_reason() is not None:
        pytest.skip(cuda_unavailable_reason())
    ds, scene, meshes, maps, cams, dist = mini
    parts = {g.obj_id: g.T_world_model for g in scene.gt if ds.models[g.obj_id].is_target}
    moving, other = sorted(parts)
    trials = np.stack([parts[moving]] + [perturb(parts[moving], a, s) for a, s in ((1, 0.5), (6, 2), (25, 15))])
    edges = maps.curvature > BOX_T_B
    args = (cams.Ks, cams.T_cam_world)
    cpu = scene_window(meshes(moving), parts[moving], [(meshes(other), parts[other])], *args, edges, dist, BOX_T_B, 12)
    cuda_meshes = [meshes(i).to("cuda") for i in (moving, other)]
    gpu = scene_window(cuda_meshes[0], parts[moving], [(cuda_meshes[1], parts[other])], *args, edges.cuda(),
                       dist.cuda(), BOX_T_B, 12)  # fmt: skip
    auto, numba, torch_backend = backend_named("auto"), backend_named("numba"), backend_named("torch")
    kernel, torch_steps = auto.window_costs(gpu, trials), torch_backend.window_costs(gpu, trials)
    assert kernel.tolist() == numba.window_costs(gpu, trials).tolist()
    np.testing.assert_allclose(kernel, auto.window_costs(cpu, trials), rtol=1e-4, atol=1e-3)
    np.testing.assert_allclose(kernel, torch_steps, rtol=1e-4, atol=1e-3)
    T_cm = torch.as_tensor(np.einsum("vij,mjk->vmik", cams.T_cam_world, np.stack([parts[moving], parts[other]])),
                           dtype=torch.float32)  # fmt: skip
    K = torch.as_tensor(cams.Ks, dtype=torch.float32)
    full = auto.scene_cost([meshes(moving), meshes(other)], T_cm, K, edges, dist, BOX_T_B)
    on_cuda = auto.scene_cost(cuda_meshes, T_cm.cuda(), K.cuda(), edges.cuda(), dist.cuda(), BOX_T_B)
    assert on_cuda == numba.scene_cost(cuda_meshes, T_cm.cuda(), K.cuda(), edges.cuda(), dist.cuda(), BOX_T_B)
    assert on_cuda == pytest.approx(full, rel=1e-4)
