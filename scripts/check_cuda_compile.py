"""Compile the CUDA kernels (the render cost's, the edge proxy's, the scene costs' and the renderer's) to PTX without a GPU: do they still build for the
device, and how lean are they?

Why. Most sessions have no GPU, and numba's CUDA simulator (what the tests run) executes the kernel as plain Python:
it accepts code the CUDA target refuses (a ``reshape`` that links to a CPU-only helper, a NumPy function the device
lacks). This script types the kernel with the argument types of a real call (a small batch prepared on the CPU) and
compiles it with numba-cuda's NVVM for a compute capability (sm_90, the H100/H200, by default), then prints the PTX's
size, its fused multiply-adds, atomics, local-memory uses and calls (a lean kernel has neither of the last two).

Needs numba-cuda and NVVM, no driver: ``pip install numba-cuda nvidia-cuda-nvcc-cu12 nvidia-cuda-nvrtc-cu12`` (and
their ``cuda-bindings``, ``cuda-core``, ``cuda-pathfinder``), with the nvrtc library on ``LD_LIBRARY_PATH``. numba
compiles device functions for the current device's compute capability; with no device there is none, so the script
tells numba's dispatcher the capability asked for (``--cc``). Exit 0: compiled, no local memory, no call; 1: compiled
but with either; 2: numba-cuda or NVVM missing (the message says what).

    python scripts/check_cuda_compile.py [--cc 9.0]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _launch_arguments() -> list:
    """The kernel's arguments of a small real call (a box in two views), as NumPy arrays and scalars."""
    import torch
    import trimesh

    from bop_cender.pose.cuda_cost import launch_plan
    from bop_cender.render.mesh import prepare_mesh

    mesh = prepare_mesh(trimesh.creation.box((40.0, 30.0, 20.0)))
    T = torch.eye(4).repeat(1, 2, 1, 1)
    T[..., 2, 3] = 300.0
    K = torch.tensor([[300.0, 0.0, 64.0], [0.0, 300.0, 48.0], [0.0, 0.0, 1.0]]).repeat(2, 1, 1)
    plan = launch_plan(mesh, T, K, 96, 128, 1.0, torch.ones(2, 96, 128), torch.zeros(2, 96, 128))
    _, arguments = plan.launches[0]
    return _as_numpy(arguments)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cc", default="9.0", help="compute capability MAJOR.MINOR (default 9.0: H100/H200)")
    args = ap.parse_args()
    cc = tuple(int(x) for x in args.cc.split("."))
    try:
        import numba_cuda  # noqa: F401 (numba-cuda, not numba's own deprecated target)
        from numba import cuda, typeof
        from numba.cuda import dispatcher
    except ImportError as error:
        print(f"check_cuda_compile: numba-cuda is not installed ({error}); pip install numba-cuda", file=sys.stderr)
        return 2

    class _Capability:  # what numba asks the current device for, with no device present
        compute_capability = cc

    dispatcher.get_current_device = lambda: _Capability()
    from bop_cender.pose import cuda_cost, cuda_edge_kernel, cuda_window_kernel
    from bop_cender.render import cuda_render

    status = 0
    for name, kernel_function, arguments in (
        ("cost kernel", cuda_cost.kernel_function, _launch_arguments),
        ("edge kernel", cuda_edge_kernel.kernel_function, _edge_arguments),
        ("window kernel", cuda_window_kernel.kernel_function, _window_arguments),
        ("render kernel", cuda_render.kernel_function, _render_arguments),
    ):
        signature = tuple(typeof(a) for a in arguments())
        try:
            ptx, _ = cuda.compile_ptx(kernel_function(), signature, cc=cc)
        except Exception as error:
            if "nvvm" in str(error).lower() or "nvrtc" in str(error).lower():
                print(f"check_cuda_compile: NVVM or nvrtc not found ({type(error).__name__}: {error})", file=sys.stderr)
                return 2
            raise
        status = max(status, _report(name, ptx, cc))
    return status


def _report(name: str, ptx: str, cc: tuple[int, ...]) -> int:
    """Print the PTX's figures; 1 where it uses local memory, calls or links to an external helper, else 0."""
    lines = ptx.splitlines()
    local = sum(".local" in line for line in lines)
    calls = [line.strip() for line in lines if line.strip().startswith("call")]
    print(f"{name}, sm_{cc[0]}{cc[1]}: {len(ptx):,} bytes of PTX, {ptx.count('fma.rn.f32')} float32 and "
          f"{ptx.count('fma.rn.f64')} float64 fused multiply-adds, {ptx.count('atom.')} atomics, "
          f"{local} local-memory lines, {len(calls)} calls")  # fmt: skip
    for line in calls[:5]:
        print("  call:", line)
    externs = [line.strip() for line in lines if line.startswith(".extern .func")]
    for line in externs[:5]:
        print("  extern:", line, "(links to a helper the device may not have)")
    return 1 if local or calls or externs else 0


def _edge_arguments() -> list:
    """The edge kernel's arguments of a small real call (a box's edges in two views), as NumPy arrays and scalars."""
    import torch
    import trimesh

    from bop_cender.pose.cuda_edge_kernel import EdgeTables
    from bop_cender.pose.edge_cost import EDGE_COINCIDENCE_MM, SAMPLES_PER_SEGMENT
    from bop_cender.pose.edge_model import edge_model_of
    from bop_cender.render.mesh import prepare_mesh

    model = edge_model_of(prepare_mesh(trimesh.creation.box((40.0, 30.0, 20.0))))
    T = torch.eye(4).repeat(2, 1, 1)
    T[:, 2, 3] = 300.0
    K = torch.tensor([[300.0, 0.0, 64.0], [0.0, 300.0, 48.0], [0.0, 0.0, 1.0]]).repeat(2, 1, 1)
    tensors = [T, torch.arange(2), K, torch.ones(2, 96, 128), torch.zeros(2, 96, 128), EdgeTables.of(model)]
    return [*_as_numpy(tensors), 1.0, SAMPLES_PER_SEGMENT, EDGE_COINCIDENCE_MM, np.zeros(2)]


def _window_arguments() -> list:
    """The scene polish kernel's arguments of a small real call (a box beside another in two views' windows)."""
    import torch
    import trimesh

    from bop_cender.pose.cuda_window_kernel import kernel_arguments, window_canvases
    from bop_cender.pose.scene_polish import scene_window
    from bop_cender.render.mesh import prepare_mesh

    mesh = prepare_mesh(trimesh.creation.box((40.0, 30.0, 20.0)))
    T_cw = np.eye(4)[None].repeat(2, 0)
    T_cw[:, 2, 3] = 300.0
    Ks = np.array([[300.0, 0.0, 64.0], [0.0, 300.0, 48.0], [0.0, 0.0, 1.0]])[None].repeat(2, 0)
    other = np.eye(4)
    other[0, 3] = 45.0
    edges = torch.zeros(2, 96, 128, dtype=torch.bool)
    edges[:, 40:50, 60] = True
    window = scene_window(mesh, np.eye(4), [(mesh, other)], Ks, T_cw, edges, torch.ones(2, 96, 128), 3.0, 12)
    arguments, _ = kernel_arguments(*window_canvases(window, np.eye(4)[None]))
    return _as_numpy(arguments)


def _render_arguments() -> list:
    """The render kernel's arguments of a small real call (two boxes packed, two canvases), as the kernel takes them."""
    import torch
    import trimesh

    from bop_cender.render.cuda_loops import exact_key_inputs
    from bop_cender.render.mesh import pack_meshes, prepare_mesh

    mesh = prepare_mesh(trimesh.creation.box((40.0, 30.0, 20.0)))
    T = torch.eye(4).repeat(2, 2, 1, 1)
    T[..., 2, 3] = 300.0
    T[:, 1, 0, 3] = 45.0
    K = torch.tensor([[300.0, 0.0, 64.0], [0.0, 300.0, 48.0], [0.0, 0.0, 1.0]]).repeat(2, 1, 1)
    canvases, _ = exact_key_inputs(pack_meshes([mesh, mesh]), T[..., :3, :3], T[..., :3, 3], K, 1.0)
    return [
        *_as_numpy(canvases),
        np.float32(1.0),
        np.zeros((2, 2), np.int64),
        np.zeros((2, 96 * 128), np.int64),
        np.zeros((2, 96, 128), np.float32),
        np.zeros((2, 96, 128, 3), np.float32),
        np.zeros((2, 96, 128), np.int64),
    ]


def _as_numpy(arguments) -> list:
    """A kernel's arguments with every tensor as a NumPy array, in named tuples too (what ``numba.typeof`` types)."""
    import torch

    def convert(x):
        if isinstance(x, torch.Tensor):
            return x.contiguous().numpy()
        if isinstance(x, tuple):
            return type(x)(*(convert(y) for y in x))
        return x

    return [convert(x) for x in arguments]


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
