"""The rasteriser's arithmetic as numba CUDA device functions: the CPU loops' source, compiled for the GPU.

Why. A kernel that renders a canvas, takes its curvature and sums its cost in one launch needs the rasteriser's
per-face and per-pixel steps as device functions. They are not written twice: :func:`device_functions` calls the
factory of :mod:`bop_cender.render.raster_arithmetic` (the source the CPU loops compile) with numba's CUDA
``jit(device=True)`` and the two steps that differ on the GPU: the z-buffer write (an atomic maximum instead of a
compare, :func:`keep_fragment_atomic`, :func:`keep_fragment_exact_atomic`) and the float32 root
(:func:`sqrt32_device`); and adds the steps only the kernels share (:func:`canvas_functions`: a block's float64 sum,
a canvas's exact z-buffer and its shading). A kernel is itself a factory's closure (``*_kernel(functions)`` in each
kernel's module) that calls these by name: every name is visible to a reader, ruff and an IDE, and nothing is
rebuilt at run time.

In numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``: the tests without a GPU) the device functions are the plain
Python functions: the simulator's own device functions swap the ``cuda`` name in their globals on every call, and its
threads' swaps race. The z-buffer writes then take a lock (:func:`keep_fragment_simulated`).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from functools import cache
from typing import NamedTuple

import numba
import numpy as np

from bop_cender.render.cuda_loops import simulator_enabled
from bop_cender.render.raster_arithmetic import RasterArithmetic, raster_arithmetic

try:  # numba's CUDA target (numba-cuda, or numba's own): where it is missing, KernelGuard says so before any use
    from numba import cuda
    from numba.cuda import libdevice
except ImportError:  # pragma: no cover (the environments we test have numba's CUDA target or its simulator)
    cuda = libdevice = None

#: Low bits of an exact z-buffer key on CUDA that hold the face id (above them: 1/z's float32 bits).
FACE_ID_BITS = 32
#: A face id's bits in an exact key.
FACE_ID_MASK = (1 << FACE_ID_BITS) - 1


class DeviceFunctions(NamedTuple):
    """The device functions the kernels call (:func:`device_functions`): the rasteriser's steps (``raster``), a
    block's float64 sum of a pair (``block_sum_pair``), and with exact keys a canvas's z-buffer (``scan_canvas_exact``)
    and the shading at a key (``shade_key``); each one's docstring says what it computes."""

    raster: RasterArithmetic
    block_sum_pair: Callable
    scan_canvas_exact: Callable
    shade_key: Callable


@cache
def device_functions(exact_keys: bool = False) -> DeviceFunctions:
    """The device functions of this process's CUDA target (compiled on first use in a kernel; the plain functions in
    numba's simulator), their z-buffer an int32 maximum of quantised keys or, with ``exact_keys``, an int64 maximum of
    exact keys (:data:`FACE_ID_BITS`: a face id is ``key & (2^32 - 1)``). Compiling needs no device
    (``numba.cuda.compile_ptx``); launching does: callers check ``cuda_loops.cuda_unavailable_reason`` first."""
    # stage 3's Nelder-Mead steps launch a few blocks at a time by design: no occupancy warning per launch
    numba.config.CUDA_LOW_OCCUPANCY_WARNINGS = False
    if simulator_enabled():
        keep = keep_fragment_exact_simulated if exact_keys else keep_fragment_simulated
        raster = raster_arithmetic(_plain, keep, sqrt32_device)
        return DeviceFunctions(raster, *canvas_functions(_plain, raster, _syncthreads_simulated))
    jit = cuda.jit(device=True)
    keep = jit(keep_fragment_exact_atomic if exact_keys else keep_fragment_atomic)
    raster = raster_arithmetic(jit, keep, jit(sqrt32_device))
    return DeviceFunctions(raster, *canvas_functions(jit, raster, cuda.syncthreads))


def _plain(py_func: Callable) -> Callable:
    """The simulator's "compiler": the plain Python function."""
    return py_func


def keep_fragment_atomic(best_key, best_w, p, q, key, f, quantised):
    """The z-buffer test at pixel ``p`` on CUDA: the larger int32 key wins, whichever thread writes first (the
    kernels use quantised keys only; ``best_w``, ``q``, ``f`` and ``quantised`` keep the CPU version's signature)."""
    cuda.atomic.max(best_key, p, np.int32(key))


def keep_fragment_exact_atomic(best_key, best_w, p, q, key, f, quantised):
    """The exact z-buffer test on CUDA (the CPU's rule for packed meshes): the larger 1/z ``q`` wins, ties to the
    larger face id ``f``, as one 64-bit atomic maximum of ``q``'s float32 bits above the face id in an int64
    ``best_key`` (a non-negative float's bits order as the float; a negative or NaN 1/z never wins, as on the CPU)."""
    if q >= 0:  # + 0: a -0.0 (>= 0, wins on the CPU) gets the bits of +0.0
        bits = np.int64(libdevice.float_as_int(np.float32(q) + np.float32(0.0)))
        cuda.atomic.max(best_key, p, (bits << FACE_ID_BITS) | np.int64(f))


_SIMULATED_ATOMICS = threading.Lock()


def keep_fragment_simulated(best_key, best_w, p, q, key, f, quantised):
    """:func:`keep_fragment_atomic` in numba's simulator, as plain Python under a lock. The simulator's own device
    functions swap the ``cuda`` name in their globals on every call, and its threads' swaps race: one thread restored
    the real module while another was in ``cuda.atomic.max`` (a failure seen once in CI)."""
    with _SIMULATED_ATOMICS:
        best_key[p] = max(best_key[p], np.int32(key))


def keep_fragment_exact_simulated(best_key, best_w, p, q, key, f, quantised):
    """:func:`keep_fragment_exact_atomic` in numba's simulator: plain Python under the simulated atomics' lock."""
    if q >= 0:
        packed = (int((np.float32(q) + np.float32(0.0)).view(np.int32)) << FACE_ID_BITS) | int(f)
        with _SIMULATED_ATOMICS:
            best_key[p] = max(int(best_key[p]), packed)


def sqrt32_device(x):
    """The float32 square root on CUDA (IEEE's: numba compiles without fast maths); the simulator runs it on a NumPy
    float32, whose root it rounds once to float32 as the CPU's ``np.sqrt`` does."""
    return np.float32(math.sqrt(x))


def _syncthreads_simulated():
    """``cuda.syncthreads`` in numba's simulator, for a plain function outside the kernel's swapped globals: the
    barrier of the simulated thread's block."""
    threading.current_thread().syncthreads()


def canvas_functions(jit: Callable, raster: RasterArithmetic, syncthreads: Callable) -> tuple[Callable, ...]:
    """``(block_sum_pair, scan_canvas_exact, shade_key)`` compiled by ``jit``, on the rasteriser's steps ``raster``
    and the block barrier ``syncthreads``."""
    face_row, key_levels, key_scale = raster.face_row, raster.key_levels, raster.key_scale
    key_plane, scan_face, shade = raster.key_plane, raster.scan_face, raster.shade

    @jit
    def block_sum_pair(sums, tid, threads, num, den):
        """Add up every thread's ``num`` and ``den`` over the block in ``sums`` (a ``(2, >= threads)`` float64 shared
        array the kernel allocates): each thread stores its pair, then a tree over the threads (``threads`` a power of
        two); on return ``sums[0, 0]`` and ``sums[1, 0]`` hold the block's totals, for every thread. It stores before
        its first barrier: a second sum into the same ``sums`` would race with threads still reading the first's
        totals (use another array, or a barrier between)."""
        sums[0, tid] = num
        sums[1, tid] = den
        syncthreads()
        step = threads // 2
        while step > 0:
            if tid < step:
                sums[0, tid] += sums[0, tid + step]
                sums[1, tid] += sums[1, tid + step]
            syncthreads()
            step //= 2

    @jit
    def scan_canvas_exact(c, tid, threads, canvas, fused, z_range, near, v0, u0, h, w, key, row):
        """Canvas ``c``'s exact z-buffer over its window (rows ``v0 ..``, columns ``u0 ..``, ``h x w``) of the
        ``canvas`` arrays (``cuda_loops.CanvasArrays``): ``key (h * w,)`` int64 set empty (-1), then every drawn face
        scanned into it by the block's threads in turn, barriers after each step; ``row`` a 12-float local array. On
        return a covered pixel's key holds its face id in the low :data:`FACE_ID_BITS` (the CPU's ``raster_window``
        with exact keys, the render of packed meshes)."""
        for p in range(tid, h * w, threads):
            key[p] = -1
        syncthreads()
        levels = key_levels(0, False)
        w_lo, scale = key_scale(z_range[c, 0], z_range[c, 1], near, levels)
        cam, px, py, Rc, Kc = canvas.cam[c], canvas.px[c], canvas.py[c], canvas.R[c], canvas.K_inv[c]
        faces = canvas.faces
        for f in range(tid, faces.shape[0], threads):
            if canvas.draw[c, f]:
                face_row(cam, faces, canvas.face_instance, canvas.corner_normals, Rc, Kc, f, fused, row)
                qa, qb, qc = key_plane(row, False, scale, w_lo)
                scan_face(px, py, faces[f, 0], faces[f, 1], faces[f, 2], f, qa, qb, qc, v0, u0, h, w, False, levels, 0,
                          fused, key, z_range[c])  # fmt: skip
        syncthreads()

    @jit
    def shade_key(c, k, i, j, v0, u0, canvas, fused, row):
        """``(depth, n0, n1, n2)`` at pixel ``(i, j)`` of canvas ``c``'s window (origin ``v0, u0``) whose exact key
        ``k`` (>= 0) names its face, at the pixel's centre in image coordinates (the CPU's ``raster_window``)."""
        face_row(canvas.cam[c], canvas.faces, canvas.face_instance, canvas.corner_normals, canvas.R[c],
                 canvas.K_inv[c], k & FACE_ID_MASK, fused, row)  # fmt: skip
        half = np.float32(0.5)
        return shade(row, np.float32(u0 + j) + half, np.float32(v0 + i) + half, fused)

    return block_sum_pair, scan_canvas_exact, shade_key
