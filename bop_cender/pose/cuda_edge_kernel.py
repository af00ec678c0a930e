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
compile or to launch, :func:`~bop_cender.pose.edge_cost.edge_costs` warns once and runs the ``dense`` torch layout
(an error the device reports later, asynchronously, surfaces in torch's next call instead).
"""

from __future__ import annotations

import functools
import math
import warnings
from functools import cache
from typing import TYPE_CHECKING

import numpy as np
import torch

from bop_cender.pose.edge_kernel import SHARED_FUNCTIONS
from bop_cender.render.cuda_loops import clone, cuda_unavailable_reason, device_functions, simulator_enabled

if TYPE_CHECKING:
    from bop_cender.pose.edge_cost import EdgeModel

#: Threads per block (one block per canvas); a power of two, the size of the float64 reduction's shared arrays.
BLOCK_THREADS = 64


def _edge_kernel(T, view, Ks, dist, occ, planes, crease, edge_first, edge_count, seg_from, seg_to, frac_a, frac_b,
                 ends, near, samples, coincidence, out):  # fmt: skip
    """``out[c]`` = the unweighted edge cost of canvas ``c = blockIdx.x`` (arguments as the CPU loop's,
    :func:`~bop_cender.pose.edge_kernel.canvas_costs`, on the device)."""
    c = cuda.blockIdx.x  # noqa: F821 (the names of this function are bound by _namespace)
    tid = cuda.threadIdx.x  # noqa: F821
    threads = cuda.blockDim.x  # noqa: F821
    v = view[c]
    P = cuda.local.array((3, 4), numba.float64)  # noqa: F821
    ex, ey, ez = canvas_projection(T, Ks, c, v, P)  # noqa: F821
    num, den = edge_sums(P, ex, ey, ez, tid, threads, v, dist, occ, planes, crease, edge_first, edge_count,  # noqa: F821
                         seg_from, seg_to, frac_a, frac_b, ends, near, samples, coincidence)  # fmt: skip
    sums = cuda.shared.array((2, BLOCK_THREADS), numba.float64)  # noqa: F821
    block_sum_pair(sums, tid, threads, num, den)  # noqa: F821
    if tid == 0:
        H, W = dist.shape[1], dist.shape[2]
        out[c] = sums[0, 0] / sums[1, 0] if sums[1, 0] > 0.0 else math.hypot(np.float64(H), np.float64(W))


@cache
def _namespace() -> dict:
    """Globals in which the CPU loop's shared functions are CUDA device functions
    (:func:`~bop_cender.render.cuda_loops.device_functions`)."""
    return device_functions(SHARED_FUNCTIONS, {"BLOCK_THREADS": BLOCK_THREADS})


def kernel_function():
    """The kernel's Python function with the shared device functions as its globals (not compiled yet)."""
    return clone(_edge_kernel, _namespace())


@cache
def _kernel():
    """The kernel compiled by numba's CUDA target (on first use)."""
    from numba import cuda

    return cuda.jit(kernel_function())


#: Why the kernel failed in this process (compilation or launch), if it did: later calls take the torch layout.
_KERNEL_FAILED: list[str] = []


def kernel_available() -> str | None:
    """Why :func:`edge_costs`' CUDA default cannot be this kernel (None: it can)."""
    return cuda_unavailable_reason() or (_KERNEL_FAILED[0] if _KERNEL_FAILED else None)


def note_failure(error: Exception) -> None:
    """Record that the kernel failed (later calls take the torch layout) and warn once."""
    _KERNEL_FAILED.append(f"the CUDA edge kernel failed ({type(error).__name__}: {error})")
    warn_once(f"the edge proxy runs in the dense torch layout on CUDA: {_KERNEL_FAILED[0]}")


@functools.cache
def warn_once(message: str) -> None:
    warnings.warn(message, RuntimeWarning, stacklevel=4)


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
    if threads < 1 or threads > BLOCK_THREADS or threads & (threads - 1):
        raise ValueError(f"threads must be a power of two up to {BLOCK_THREADS}, got {threads}")
    device = T.device
    if device.type != "cuda" and not simulator_enabled():
        raise ValueError(f"the CUDA edge kernel takes CUDA tensors (or CPU ones under the simulator), got {device}")
    C = int(T.shape[0])
    out = torch.empty(C, dtype=torch.float64, device=device)
    if C == 0:
        return out.float()
    proj = model.projection
    first, count = model.edge_segments.unbind(1)
    occ = torch.zeros((0, 1, 1), dtype=torch.float32, device=device) if occ is None else occ
    tensors = [T, view, Ks, dist, occ, model.planes, model.crease, first, count, proj.seg_from, proj.seg_to,
               proj.frac_a, proj.frac_b, proj.ends]  # fmt: skip
    tensors = [x.contiguous() for x in tensors]
    kernel = _kernel()
    if simulator_enabled():  # numba's simulator runs the kernel on NumPy arrays
        arrays = [x.detach().numpy() for x in (*tensors, out)]
        kernel[C, threads](*arrays[:-1], float(near), int(samples), float(coincidence_mm), arrays[-1])
        return out.float()
    from numba import cuda

    with cuda.gpus[device.index if device.index is not None else torch.cuda.current_device()]:
        # the arrays and the stream inside the device's context: on cuda:1 they would otherwise bind device 0's
        arrays = [cuda.as_cuda_array(x.detach()) for x in (*tensors, out)]
        stream = cuda.external_stream(torch.cuda.current_stream(device).cuda_stream)
        kernel[C, threads, stream](*arrays[:-1], float(near), int(samples), float(coincidence_mm), arrays[-1])
    return out.float()
