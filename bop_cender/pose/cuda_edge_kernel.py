"""The edge proxy as one CUDA kernel: a thread block per canvas, its threads sharing the object's edges.

Why. Stage 3's Nelder-Mead steps cost 1 to 8 poses at a time on the edge proxy, thousands of calls per scene. On
an H200 the torch layout CUDA ran until now (``dense``: every segment costed with a 0/1 weight, fixed shapes)
took 2.6 ms for a step of 3 poses, 1,138 calls/s against 1,919-2,228 on 2 CPU cores
(``results/bench/run_*nvidia-h200.md``): each call is a few dozen small torch kernels, each of them a launch.
Here a call is one launch: block ``c`` takes canvas ``c`` (a candidate in one view), each of its threads sums the
drawn segments of every ``threads``-th edge (:func:`~bop_cender.pose.edge_kernel.edge_sums`, the CPU loop's own
source compiled again as a CUDA device function), and the block adds the threads' sums in float64.

Rounding. The sums are those of the CPU loop in another order (per thread, then a tree over the threads), and on
a GPU NVVM contracts multiply-adds: the costs agree with the CPU's to float32 rounding, not bit for bit. In numba's
CUDA simulator (what the tests run without a GPU) the device functions are the plain Python ones.

numba's CUDA target is optional (:mod:`bop_cender.render.cuda_loops`): where it is missing or the kernel fails to
compile or to launch, the ``auto`` backend (:meth:`~bop_cender.pose.backend.Backend.edge_costs`) warns once and runs the ``dense`` torch layout
(an error the device reports later, asynchronously, surfaces in torch's next call instead).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import cache
from typing import NamedTuple

import numba
import numpy as np
import torch

from bop_cender.pose.edge_kernel import edge_arithmetic
from bop_cender.pose.edge_model import EdgeModel
from bop_cender.render.cuda_device import device_functions
from bop_cender.render.cuda_loops import KernelGuard, check_device, check_threads, simulator_enabled

try:  # numba's CUDA target: where it is missing, the guard says so and the edge proxy takes a torch layout
    from numba import cuda
except ImportError:  # pragma: no cover
    cuda = None

#: Threads per block (one block per canvas); a power of two, the size of the float64 reduction's shared arrays.
BLOCK_THREADS = 64


def edge_kernel(functions: EdgeDeviceFunctions):
    """The edge kernel's Python function on ``functions`` (:func:`edge_device_functions`; ``numba.cuda.jit`` or
    ``numba.cuda.compile_ptx`` take it)."""
    canvas_projection, edge_sums, block_sum_pair = (
        functions.canvas_projection,
        functions.edge_sums,
        functions.block_sum_pair,
    )

    def canvas_costs(T, view, Ks, dist, occ, tables: EdgeTables, near, samples, coincidence, out):
        """``out[c]`` = the unweighted edge cost of canvas ``c = blockIdx.x`` (arguments as the CPU loop's,
        :func:`~bop_cender.pose.edge_kernel.canvas_costs`, on the device, the edge model's tables as one
        :class:`EdgeTables`)."""
        c = cuda.blockIdx.x
        tid = cuda.threadIdx.x
        threads = cuda.blockDim.x
        v = view[c]
        P = cuda.local.array((3, 4), numba.float64)
        ex, ey, ez = canvas_projection(T, Ks, c, v, P)
        num, den = edge_sums(P, ex, ey, ez, tid, threads, v, dist, occ, tables.planes, tables.crease,
                             tables.edge_first, tables.edge_count, tables.seg_from, tables.seg_to, tables.frac_a,
                             tables.frac_b, tables.ends, near, samples, coincidence)  # fmt: skip
        sums = cuda.shared.array((2, BLOCK_THREADS), numba.float64)
        block_sum_pair(sums, tid, threads, num, den)
        if tid == 0:
            H, W = dist.shape[1], dist.shape[2]
            out[c] = sums[0, 0] / sums[1, 0] if sums[1, 0] > 0.0 else math.hypot(np.float64(H), np.float64(W))

    return canvas_costs


class EdgeDeviceFunctions(NamedTuple):
    """What the edge kernel calls: the CPU loop's own steps (:func:`~bop_cender.pose.edge_kernel.edge_arithmetic`)
    compiled for the device, and a block's float64 sum."""

    canvas_projection: Callable
    edge_sums: Callable
    block_sum_pair: Callable


@cache
def edge_device_functions() -> EdgeDeviceFunctions:
    """The edge arithmetic as this process's CUDA device functions (the plain functions in numba's simulator)."""
    functions = device_functions()
    jit = (lambda f: f) if simulator_enabled() else cuda.jit(device=True)
    arithmetic = edge_arithmetic(jit)
    return EdgeDeviceFunctions(arithmetic.canvas_projection, arithmetic.edge_sums, functions.block_sum_pair)


def kernel_function():
    """The kernel's Python function on this process's device functions (not compiled yet:
    ``scripts/check_cuda_compile.py`` compiles it to PTX)."""
    return edge_kernel(edge_device_functions())


class EdgeTables(NamedTuple):
    """An edge model's tables as the kernel takes them (:class:`~bop_cender.pose.edge_model.EdgeModel`,
    :class:`~bop_cender.pose.edge_model.SegmentProjection`), contiguous on the device."""

    planes: torch.Tensor
    crease: torch.Tensor
    edge_first: torch.Tensor
    edge_count: torch.Tensor
    seg_from: torch.Tensor
    seg_to: torch.Tensor
    frac_a: torch.Tensor
    frac_b: torch.Tensor
    ends: torch.Tensor

    @staticmethod
    def of(model: EdgeModel) -> EdgeTables:
        proj = model.projection
        first, count = model.edge_segments.unbind(1)
        tables = (model.planes, model.crease, first, count, proj.seg_from, proj.seg_to, proj.frac_a, proj.frac_b,
                  proj.ends)  # fmt: skip
        return EdgeTables(*(x.contiguous() for x in tables))


#: The kernel's standing in this process (compiled on first use; where it cannot run, the dense torch layout).
GUARD = KernelGuard("the CUDA edge kernel", "the edge proxy runs in the dense torch layout on CUDA", kernel_function)


def cuda_canvas_costs(
    model: EdgeModel,
    T: torch.Tensor,
    view: torch.Tensor,
    Ks: torch.Tensor,
    dist: torch.Tensor,
    occ: torch.Tensor | None,
    near: float,
    samples: int,
    coincidence_mm: float,
    threads: int = BLOCK_THREADS,
) -> torch.Tensor:
    """Unweighted cost ``(C,)`` float32 of C canvases (poses ``T (C, 4, 4)`` in views ``view (C,)``) by the CUDA
    kernel, as :func:`~bop_cender.pose.edge_kernel.kernel_canvas_costs` gives them on the CPU.

    Args:
        model, T, view, Ks, dist, occ, near, samples, coincidence_mm: as ``kernel_canvas_costs``, every tensor on one
            CUDA device (or the CPU under numba's CUDA simulator).
        threads: threads per block, a power of two up to :data:`BLOCK_THREADS` (the tests use fewer: the simulator
            runs each thread as a Python thread).

    Raises:
        ValueError: ``threads`` out of range, or CPU tensors outside the simulator.
    """
    check_threads(threads, BLOCK_THREADS)
    device = T.device
    check_device(device, "the CUDA edge kernel")
    C = int(T.shape[0])
    out = torch.empty(C, dtype=torch.float64, device=device)
    if C == 0:
        return out.float()
    occ = torch.zeros((0, 1, 1), dtype=torch.float32, device=device) if occ is None else occ
    tensors = [x.contiguous() for x in (T, view, Ks, dist, occ)]
    GUARD.launch(C, threads, [*tensors, EdgeTables.of(model), float(near), int(samples), float(coincidence_mm), out],
                 device)  # fmt: skip
    return out.float()
