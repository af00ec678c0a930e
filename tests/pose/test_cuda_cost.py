"""The CUDA cost kernel (``bop_cender.pose.cuda_cost``): the CPU loops' costs, one launch per call.

Without a GPU the kernel runs in numba's CUDA simulator (a subprocess with ``NUMBA_ENABLE_CUDASIM=1``: every CUDA
thread a Python thread, no multiply-add contraction), where it must repeat the CPU's compiled loops bit for bit:
candidates inside the images, cut by the border, out of every view, behind placed objects. On a GPU (``-m cuda``)
the ``auto`` backend takes it and must give the torch atlases' costs to float32 rounding.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from bop_cender.pose.backend import backend_named
from bop_cender.render.mesh import prepare_mesh

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))
from cuda_simulator import simulated_ok_lines  # noqa: E402

#: What the simulated run checks, printed line by line ("ok ...") for the test to read.
_SIMULATED = textwrap.dedent(
    """
    import sys
    sys.path[:0] = [{tests!r} + "/pose", {tests!r} + "/render"]
    import numpy as np, torch, trimesh
    from reference import pose
    from test_cost import H, W, rig, target
    from bop_cender.pose.cost_kernel import compiled_candidate_costs
    from bop_cender.pose.cuda_cost import cuda_candidate_costs
    from bop_cender.render.candidate_curvature import prepare_candidates
    from bop_cender.render.compiled_raster import ADDCMUL_FUSED
    from bop_cender.render.mesh import prepare_mesh

    mesh = prepare_mesh(trimesh.creation.box((40.0, 30.0, 20.0)))
    T_cw, Ks = rig()
    dist = target(mesh, T_cw, Ks)
    rng = np.random.default_rng(4)
    T_wm = np.stack([pose(tuple(rng.uniform(-180, 180, 3)), tuple(rng.uniform(-12, 12, 3))) for _ in range(3)])
    T_wm[1, :3, 3] += [-90, 40, 0]  # cut by an image border
    T_wm[2, :3, 3] += [1500, 1500, 1500]  # in front of every camera, outside every image
    T = torch.as_tensor(np.einsum("vij,bjk->bvik", T_cw, T_wm), dtype=torch.float32)
    K = torch.as_tensor(Ks, dtype=torch.float32)
    occ = torch.zeros((3, H, W))
    occ[:, 30:70, 40:90] = 300.0  # a placed object's face through the middle of the views
    occ[1, 40:60, 50:70] = 305.0
    for name, occluder, scratch in (("free", None, 1 << 30), ("occluded", occ, 1)):  # 1 byte: a launch per canvas
        cpu = compiled_candidate_costs(prepare_candidates(mesh, T, K, H, W, occluder_depth=occluder), dist)
        sim = cuda_candidate_costs(mesh, T, K, H, W, 1.0, dist, occluder, threads=8, fused=ADDCMUL_FUSED,
                                   scratch_bytes=scratch)  # fmt: skip
        assert sim.dtype == torch.float32 and sim.shape == (9,), sim
        # the same float32 arithmetic; the float64 sums in another order, rounded to float32
        torch.testing.assert_close(sim, cpu, rtol=2e-7, atol=0)
        print("ok", name, sim.tolist())
    big = prepare_mesh(trimesh.creation.icosphere(subdivisions=6, radius=20.0))  # 81,920 faces: exact keys,
    print("ok exact keys", cuda_candidate_costs(big, T[:1], K, H, W, 1.0, dist) is None)  # left to torch
    T_near = T.clone()
    T_near[0, 0, 2, 3] = 5.0  # a vertex behind the near plane
    print("ok near plane", cuda_candidate_costs(mesh, T_near[:1], K, H, W, 1.0, dist) is None)
    for threads in (0, 3, 256):
        try:
            cuda_candidate_costs(mesh, T[:1], K, H, W, 1.0, dist, threads=threads)
        except ValueError as error:
            print("ok threads", threads, error)
    """
)


def test_the_kernel_repeats_the_cpu_loops_in_numbas_cuda_simulator() -> None:
    lines = simulated_ok_lines(_SIMULATED)
    assert [line.split()[1] for line in lines] == ["free", "occluded", "exact", "near", "threads", "threads", "threads"]
    assert lines[2].endswith("True") and lines[3].endswith("True")
    free, occluded = (np.array(eval(line.split(" ", 2)[2])) for line in lines[:2])  # noqa: S307 (our own output)
    assert free[-3:] == pytest.approx(np.full(3, np.hypot(96, 128)), rel=1e-6)  # out of view: the image diagonal
    assert (free[:3] < 20).all()  # the first candidate, near the part, in every view
    assert not np.array_equal(free, occluded)  # the placed object hid something


def test_the_kernel_refuses_cpu_tensors_outside_the_simulator() -> None:
    from bop_cender.pose.cuda_cost import cuda_candidate_costs
    from bop_cender.render.cuda_loops import simulator_enabled

    if simulator_enabled():
        pytest.skip("the simulator takes CPU tensors")
    mesh = prepare_mesh(trimesh.creation.box((40.0, 30.0, 20.0)))
    with pytest.raises(ValueError, match="CUDA tensors"):
        cuda_candidate_costs(mesh, torch.eye(4).repeat(1, 1, 1, 1), torch.eye(3)[None], 8, 8, 1.0, torch.zeros(1, 8, 8))


def test_the_backends_take_the_kernel_through_its_guard_and_say_where_it_does_not_apply(monkeypatch, kernel_standing):
    """On CUDA the ``auto`` and ``numba`` backends take the cost kernel where it runs (the guard's rules,
    ``tests/render/test_kernel_guard.py``); where it declines a call (a vertex behind the near plane, a mesh of more
    than 2^15 faces) both leave it to the torch atlases with one warning; where numba's CUDA target is missing ``auto``
    warns once and takes the atlases, ``numba`` says why it cannot run."""
    from types import SimpleNamespace

    from bop_cender.pose import cuda_cost
    from bop_cender.pose.backend import NumbaBackend

    mesh = prepare_mesh(trimesh.creation.box((40.0, 30.0, 20.0)))
    args = (torch.eye(4)[None, None], torch.eye(3)[None], 8, 8, 1.0, torch.zeros(1, 8, 8), None)
    auto, numba = NumbaBackend(), NumbaBackend(insist=True)
    kernel_standing(cuda_cost.GUARD)
    monkeypatch.setattr(cuda_cost, "cuda_candidate_costs", lambda *a, **k: torch.ones(1))
    assert (
        auto.kernel_candidate_costs(mesh, *args).tolist() == [1.0] == numba.kernel_candidate_costs(mesh, *args).tolist()
    )
    monkeypatch.setattr(cuda_cost, "cuda_candidate_costs", lambda *a, **k: None)  # does not apply
    for backend in (auto, numba):
        with pytest.warns(RuntimeWarning, match="the CUDA cost kernel leaves geometry behind the near plane"):
            assert backend.kernel_candidate_costs(mesh, *args) is None
        large = SimpleNamespace(faces=torch.zeros((1 << 15) + 1, 3))
        with pytest.warns(RuntimeWarning, match="meshes of at most 2.15 faces"):
            assert backend.kernel_candidate_costs(large, *args) is None
    kernel_standing(cuda_cost.GUARD, "numba.cuda finds no CUDA driver or device")
    with pytest.warns(RuntimeWarning, match="torch atlases on CUDA: numba.cuda finds no CUDA driver"):
        assert auto.kernel_candidate_costs(mesh, *args) is None
    with pytest.raises(
        RuntimeError, match="needs the CUDA cost kernel, which cannot run here: numba.cuda finds no CUDA driver"
    ):
        numba.kernel_candidate_costs(mesh, *args)


def test_launch_groups_fit_the_scratch_and_cover_every_canvas_once() -> None:
    from bop_cender.pose.cuda_cost import _launch_groups

    extent = np.array([[10, 8], [5, 30], [7, 9], [40, 9], [3, 2]])
    groups = _launch_groups(extent, 12 * 400)
    assert sorted(np.concatenate([g.canvases for g in groups]).tolist()) == [0, 1, 2, 3, 4]
    for g in groups:
        assert g.rows * g.widest * 12 <= 12 * 400 or len(g.canvases) == 1
        assert g.rows == extent[g.canvases, 0].sum() and g.widest == extent[g.canvases, 1].max()
        assert g.row_base.tolist() == np.concatenate([[0], np.cumsum(extent[g.canvases, 0])[:-1]]).tolist()
    # by width 2, 8, 9, 9, 30: 20 rows x 9 fit 400 floats, 60 x 9 do not; 40 x 9 do, 45 x 30 not
    assert [g.canvases.tolist() for g in groups] == [[4, 0, 2], [3], [1]]
    assert [len(g.canvases) for g in _launch_groups(extent, 1)] == [1] * 5  # too small for any: one canvas each


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_on_cuda_the_kernel_gives_the_atlases_costs() -> None:
    try:
        from tests.pose.test_cost import H, W, rig, target
        from tests.pose.test_cost_kernel import _candidates
        from tests.render.reference import bracket
    except ImportError:
        sys.path[:0] = [str(ROOT / "tests" / "pose"), str(ROOT / "tests" / "render")]
        from reference import bracket
        from test_cost import H, W, rig, target
        from test_cost_kernel import _candidates
    from bop_cender.render.cuda_loops import cuda_unavailable_reason

    if cuda_unavailable_reason() is not None:
        pytest.skip(cuda_unavailable_reason())
    mesh = prepare_mesh(bracket(16))
    T_cw, Ks = rig()
    dist = target(mesh, T_cw, Ks)
    weights = torch.tensor([1.0, 0.7, 1.3])
    T = torch.as_tensor(np.einsum("vij,bjk->bvik", T_cw, _candidates(12, seed=4)), dtype=torch.float32)
    occ = torch.zeros((3, H, W))
    occ[:, 30:70, 40:90] = 300.0
    for occluder in (None, occ):
        cpu = backend_named("auto").candidate_costs(mesh, T, Ks, H, W, dist, weights, occluder_depth=occluder)
        args = (mesh.to("cuda"), T.cuda(), torch.as_tensor(Ks).cuda(), H, W, dist.cuda(), weights.cuda())
        occ_cuda = None if occluder is None else occluder.cuda()
        kernel = backend_named("auto").candidate_costs(*args, occluder_depth=occ_cuda)
        atlases = backend_named("torch").candidate_costs(*args, occluder_depth=occ_cuda)
        assert kernel.device.type == "cuda"
        assert torch.equal(kernel, backend_named("numba").candidate_costs(*args, occluder_depth=occ_cuda))
        torch.testing.assert_close(kernel.cpu(), atlases.cpu(), rtol=1e-4, atol=1e-3)
        torch.testing.assert_close(kernel.cpu(), cpu, rtol=1e-4, atol=1e-3)


def test_the_compile_check_records_a_real_calls_arguments_and_compiles_or_says_what_is_missing() -> None:
    """``scripts/check_cuda_compile.py`` types the kernel from a real call's arguments (one per kernel parameter) and
    compiles it for sm_90 where numba-cuda and NVVM are installed; elsewhere (CI) it says what is missing, exit 2."""
    import importlib.util
    import inspect

    from bop_cender.pose import cuda_cost, cuda_edge_kernel, cuda_window_kernel
    from bop_cender.render import cuda_render

    sys.path.insert(0, str(ROOT / "scripts"))
    import check_cuda_compile

    def plain(x) -> bool:  # what a kernel takes: arrays, scalars, or a named tuple of arrays
        if isinstance(x, tuple):
            return hasattr(x, "_fields") and all(isinstance(y, np.ndarray) for y in x)
        return isinstance(x, np.ndarray) or np.isscalar(x) or isinstance(x, bool)

    for arguments, module in ((check_cuda_compile._launch_arguments(), cuda_cost),
                              (check_cuda_compile._edge_arguments(), cuda_edge_kernel),
                              (check_cuda_compile._window_arguments(), cuda_window_kernel),
                              (check_cuda_compile._render_arguments(), cuda_render)):  # fmt: skip
        kernel = module.kernel_function()
        assert len(arguments) == len(inspect.signature(kernel).parameters) <= 15, module.__name__
        assert all(plain(a) for a in arguments), module.__name__
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "check_cuda_compile.py")], capture_output=True,
                          text=True, timeout=300, env={**os.environ, "PYTHONPATH": str(ROOT)})  # fmt: skip
    assert "Traceback" not in done.stderr
    if importlib.util.find_spec("numba_cuda") is None:
        assert done.returncode == 2 and "numba-cuda is not installed" in done.stderr
    elif done.returncode == 2:
        assert "NVVM or nvrtc not found" in done.stderr
    else:
        assert done.returncode == 0 and "0 local-memory lines, 0 calls" in done.stdout, done.stdout
