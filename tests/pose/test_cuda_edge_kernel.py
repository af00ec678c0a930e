"""The edge proxy's CUDA kernel (``bop_cender.pose.cuda_edge_kernel``): the CPU loop's costs, one launch per call.

Without a GPU the kernel runs in numba's CUDA simulator (a subprocess with ``NUMBA_ENABLE_CUDASIM=1``: every CUDA
thread a Python thread, the shared device functions the plain Python ones), where it must give the CPU loop's costs
to float64 rounding (the threads' sums are added in another order): poses near the part, out of some views, behind
the cameras, non-finite, with and without placed objects, for the full and a sparse edge model. On a GPU
``tests/pose/test_edge_cost.py::test_cuda_gives_the_cpu_costs`` (``-m cuda``) checks it as CUDA's default layout.
"""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch

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
    from method_data import gt_of, perturb
    from bop_cender.pose.cuda_edge_kernel import cuda_canvas_costs
    from bop_cender.pose.edge_cost import EDGE_COINCIDENCE_MM, SAMPLES_PER_SEGMENT
    from bop_cender.pose.edge_model import edge_model_of
    from bop_cender.pose.edge_kernel import kernel_canvas_costs

    ds, scene, meshes, maps, cams, dist = method_data.mini_scene(Path(tempfile.mkdtemp()) / "dimo")
    V, H, W = dist.shape
    Ks = torch.as_tensor(np.stack([v.K for v in scene.views]), dtype=torch.float32)
    T_cw = np.stack([v.T_cam_world for v in scene.views])
    g = gt_of(scene, 3).T_world_model
    poses = np.stack([perturb(g, a, s) for a, s in ((0, 0), (5, 3), (20, 12), (0, 0), (0, 0), (0, 0))])
    poses[2, :3, 3] += [60.0, 0.0, 0.0]  # partly out of some views
    poses[3, :3, 3] -= 5000.0 * T_cw[0, 2, :3]  # behind the first camera
    poses[4, 0, 0] = np.nan
    poses[5, :3, 3] = np.inf
    T = torch.as_tensor(np.einsum("vij,njk->nvik", T_cw, poses), dtype=torch.float32).reshape(-1, 4, 4)
    view = torch.arange(T.shape[0]) % V
    occ = torch.zeros((V, H, W))
    occ[:, :, : W // 2] = 300.0
    model = edge_model_of(meshes(3))
    for name, m in (("full", model), ("sparse", model.sparse(40))):
        for o_name, o in (("free", None), ("occluded", occ)):
            args = (m, T, view, Ks, dist, o, 1.0, SAMPLES_PER_SEGMENT, EDGE_COINCIDENCE_MM)
            cpu = kernel_canvas_costs(*args).numpy()
            sim = cuda_canvas_costs(*args, threads=4).numpy()
            print("ok", name, o_name, float(np.max(np.abs(sim - cpu))), sim.tolist())
    first = (model, T[: 2 * V], view[: 2 * V], Ks, dist, None, 1.0, SAMPLES_PER_SEGMENT, EDGE_COINCIDENCE_MM)
    by_default = cuda_canvas_costs(*first)  # the default block size
    print("ok layout", float(torch.max(torch.abs(by_default - kernel_canvas_costs(*first)))))
    for threads in (0, 3, 128):
        try:
            cuda_canvas_costs(*args, threads=threads)
        except ValueError as error:
            print("ok threads", threads, error)
    """
)


def test_the_kernel_gives_the_cpu_loops_costs_in_numbas_cuda_simulator() -> None:
    lines = [line.split(" ", 4) for line in simulated_ok_lines(_SIMULATED, compares_compiled_raster=False)]
    assert [line[1] for line in lines] == [
        "full",
        "full",
        "sparse",
        "sparse",
        "layout",
        "threads",
        "threads",
        "threads",
    ]
    for _, name, occluded, error, costs in lines[:4]:
        assert float(error) < 1e-5, (name, occluded, error)  # float32 costs of float64 sums in another order
        costs = np.array(eval(costs))  # noqa: S307 (our own output)
        per_pose = costs.reshape(6, -1)
        assert np.isfinite(costs).all()
        assert (per_pose[3:] == per_pose[3:].max()).all()  # behind / non-finite: the image diagonal in every view
        assert per_pose[0].min() < 1.0 and (per_pose[1] >= per_pose[0]).all()  # smallest at the GT pose
    free, occluded = (np.array(eval(line[4])) for line in lines[:2])  # noqa: S307
    assert not np.array_equal(free, occluded)  # the placed object hid something
    assert float(lines[4][2]) < 1e-5
    assert [line[2] for line in lines[5:]] == ["0", "3", "128"]


def test_the_kernel_refuses_cpu_tensors_outside_the_simulator() -> None:
    from bop_cender.pose.cuda_edge_kernel import cuda_canvas_costs
    from bop_cender.pose.edge_model import edge_model_of
    from bop_cender.render.cuda_loops import simulator_enabled
    from bop_cender.render.mesh import prepare_mesh

    if simulator_enabled():
        pytest.skip("the simulator takes CPU tensors")
    import trimesh

    model = edge_model_of(prepare_mesh(trimesh.creation.box((40.0, 30.0, 20.0))))
    T = torch.eye(4)[None, None].clone()
    T[..., 2, 3] = 300.0
    K = torch.tensor([[[100.0, 0.0, 16.0], [0.0, 100.0, 16.0], [0.0, 0.0, 1.0]]])
    with pytest.raises(ValueError, match="CUDA tensors"):
        cuda_canvas_costs(model, T[0], torch.zeros(1, dtype=torch.int64), K, torch.zeros(1, 32, 32), None, 1.0, 2, 1.0)
