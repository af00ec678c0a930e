"""The compiled renderer's arithmetic on CUDA: the same Python source as the CPU loops, compiled by numba's CUDA target.

Why. On a GPU the torch renderer's candidate path launches about 730 kernels and synchronises 77 times per cost
call (``results/bench/run_*nvidia-h200.md``), so a call costs 13-24 ms whatever its size. A kernel that renders a
canvas, takes its curvature and sums its cost in one launch (:mod:`bop_cender.pose.cuda_cost`) needs the
rasteriser's per-face and per-pixel steps as device functions. They are not written twice:
:data:`~bop_cender.render.compiled_raster.SHARED_FUNCTIONS` holds the plain Python functions that the CPU loops
compile, and :func:`device_namespace` compiles each again for CUDA with its global names bound to the CUDA versions
(the z-buffer write, :func:`keep_fragment`, becomes an atomic maximum).

numba's CUDA target is optional: it needs ``numba.cuda`` with a driver (``pip install numba-cuda``, present in
the NVIDIA images we benchmark on) or numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``), where the kernels run as
Python threads on the CPU: how the tests check them against the CPU loops on machines without a GPU.
"""

from __future__ import annotations

import functools
import math
import re
import threading
import types
import warnings
from collections.abc import Callable
from functools import cache
from typing import TypeVar

import numpy as np
import torch


def simulator_enabled() -> bool:
    """Whether numba's CUDA simulator is on (``NUMBA_ENABLE_CUDASIM=1`` before numba was imported)."""
    from numba import config

    return bool(config.ENABLE_CUDASIM)


@cache
def cuda_unavailable_reason() -> str | None:
    """Why numba's CUDA kernels cannot run here (None: they can, on a GPU or in the simulator)."""
    try:
        from numba import cuda
    except Exception as error:  # an absent or broken numba-cuda: the torch path serves instead
        return f"numba.cuda cannot be imported ({type(error).__name__}: {error})"
    if simulator_enabled():
        return None
    try:
        if not cuda.is_available():
            return "numba.cuda finds no CUDA driver or device"
    except Exception as error:  # the driver's own error, e.g. a version mismatch
        return f"numba.cuda cannot reach the device ({type(error).__name__}: {error})"
    return None


def _described(error: Exception) -> str:
    """``error`` as ``Type: message``, without the terminal highlighting numba puts in its messages."""
    message = _HIGHLIGHT.sub("", str(error))
    return f"{type(error).__name__}: {message}"


_HIGHLIGHT = re.compile(r"\x1b\[[0-9;]*m")  # a terminal's colour and weight codes


def is_kernel_error(error: Exception) -> bool:
    """Whether ``error`` is numba's or the CUDA driver's (compilation, linking, launch), not the call's own (its
    inputs, torch's memory)."""
    return type(error).__module__.split(".")[0] in ("numba", "numba_cuda", "cuda")


T_out = TypeVar("T_out")


class KernelGuard:
    """One CUDA kernel's standing in this process: compiled on first use (:attr:`kernel`), launched on torch's stream
    (:meth:`launch`), and run by :meth:`run`, which tells its caller when to take its torch path instead: where
    numba's CUDA target is missing (numba-cuda, a driver), or the kernel failed to compile or to launch (for the rest
    of the process), or one call failed on its own (out of memory: that call). Each reason is warned once.

    Args:
        name: the kernel in messages ("the CUDA window kernel").
        fallback: what the caller does without it ("the scene costs run their torch steps on CUDA").
        build: the kernel's Python function with its device functions as globals (``numba.cuda.jit`` compiles it).
    """

    def __init__(self, name: str, fallback: str, build: Callable[[], types.FunctionType]) -> None:
        self.name = name
        self.fallback = fallback
        self.build = build
        #: Why the kernel failed in this process, if it did: later calls take the caller's torch path.
        self.failed: list[str] = []
        self._warned: set[str] = set()

    @functools.cached_property
    def kernel(self):
        """The kernel compiled by numba's CUDA target (on first use: a few seconds)."""
        from numba import cuda

        return cuda.jit(self.build())

    def unavailable(self) -> str | None:
        """Why the kernel cannot run here (None: it can, on a GPU or in the simulator)."""
        return cuda_unavailable_reason() or (self.failed[0] if self.failed else None)

    def warn_once(self, message: str, key: str | None = None) -> None:
        """Warn ``message`` the first time its ``key`` (default: the message) comes up in this process."""
        key = message if key is None else key
        if key not in self._warned:
            self._warned.add(key)
            warnings.warn(message, RuntimeWarning, stacklevel=4)

    def note_failure(self, error: Exception) -> None:
        """Record that the kernel failed (later calls take the torch path) and warn once."""
        self.failed.append(f"{self.name} failed ({_described(error)})")
        self.warn_once(f"{self.fallback}: {self.failed[0]}")

    def run(self, compute: Callable[[], T_out | None], compiled: bool | None) -> T_out | None:
        """``compute()`` (a call of the kernel) where it can run; None where the caller's torch path is to serve:
        ``compute`` returned None (the kernel does not apply), or, with ``compiled=None``, the kernel is unavailable
        or failed (warned once).

        Raises:
            RuntimeError: ``compiled=True`` (the caller asked for the kernel) where the kernel is unavailable; the
                kernel's own error where it failed with ``compiled=True``.
        """
        reason = self.unavailable()
        if reason is not None:
            if compiled:
                hint = " (pip install numba-cuda)" if cuda_unavailable_reason() else ""
                raise RuntimeError(f"this call needs {self.name}, which cannot run here: {reason}{hint}")
            self.warn_once(f"{self.fallback}: {reason}")
            return None
        try:
            return compute()
        except Exception as error:  # the torch path stays available
            if compiled:
                raise
            if is_kernel_error(error):  # numba's compilation, the driver or the launch: for the rest of the process
                self.note_failure(error)
            else:  # e.g. out of memory for this call's scratch: this call only
                message = f"{self.fallback} for a call: {self.name}'s call failed ({_described(error)})"
                self.warn_once(message, key=f"call failed: {type(error).__name__}")  # once per kind, not per size
            return None

    def launch(self, blocks: int, threads: int, arguments: list, device: torch.device) -> None:
        """Launch the kernel on ``blocks`` blocks of ``threads`` threads with ``arguments`` (tensors, as CUDA arrays
        on torch's current stream of ``device``, and scalars); in numba's simulator on the tensors' NumPy views."""
        if simulator_enabled():  # numba's simulator runs the kernel on NumPy arrays
            self.kernel[blocks, threads](*(x.detach().numpy() if isinstance(x, torch.Tensor) else x for x in arguments))
            return
        from numba import cuda

        with cuda.gpus[device.index if device.index is not None else torch.cuda.current_device()]:
            # the arrays and the stream inside the device's context: on cuda:1 they would otherwise bind device 0's
            arrays = [cuda.as_cuda_array(x.detach()) if isinstance(x, torch.Tensor) else x for x in arguments]
            stream = cuda.external_stream(torch.cuda.current_stream(device).cuda_stream)
            self.kernel[blocks, threads, stream](*arrays)


def check_threads(threads: int, limit: int) -> None:
    """Refuse a block size that is not a power of two up to ``limit`` (the kernels' float64 reductions need one)."""
    if threads < 1 or threads > limit or threads & (threads - 1):
        raise ValueError(f"threads must be a power of two up to {limit}, got {threads}")


def check_device(device: torch.device, what: str) -> None:
    """Refuse tensors that are not on CUDA, but under numba's simulator (which takes CPU tensors)."""
    if device.type != "cuda" and not simulator_enabled():
        raise ValueError(f"{what} takes CUDA tensors (or CPU ones under the simulator), got {device}")


def exact_key_inputs(
    packed, R: torch.Tensor, t: torch.Tensor, K: torch.Tensor, near: float
) -> tuple[list, torch.Tensor]:
    """What the exact-key kernels (the renderer's and the scene costs') read of C canvases of packed meshes: the nine
    loop tensors (:func:`~bop_cender.render.compiled_raster.loop_tensors`, contiguous), the multiply-add rounding
    (fused on a GPU, as torch's CUDA kernels round; in numba's simulator the CPU's as probed, so that it repeats the
    CPU loops' bits), the canvases' vertex depth range ``z_range (C, 2)``; and, apart, the least vertex depth (a 0-d
    tensor, read back with the call's results: a vertex behind the near plane leaves the call to the torch path).
    Packed meshes know their vertex counts: nothing here waits for the device."""
    from bop_cender.render.compiled_raster import ADDCMUL_FUSED, loop_tensors

    inputs = loop_tensors(packed, R, t, K, near, check_near=False)
    z = inputs[0][..., 2]  # (C, N) camera-space vertex depths
    z_range = torch.stack([z.amin(1), z.amax(1)], 1).contiguous()
    fused = bool(ADDCMUL_FUSED) if simulator_enabled() else True
    return [*(x.contiguous() for x in inputs[:9]), fused, z_range], z_range[:, 0].amin()


def _keep_fragment_atomic(best_key, best_w, p, q, key, f, quantised):
    """The z-buffer test at pixel ``p`` on CUDA: the larger int32 key wins, whichever thread writes first (the
    kernels use quantised keys only; ``best_w``, ``q``, ``f`` and ``quantised`` keep the CPU version's signature)."""
    cuda.atomic.max(best_key, p, np.int32(key))  # noqa: F821 (bound in device_namespace)


_SIMULATED_ATOMICS = threading.Lock()


def _keep_fragment_simulated(best_key, best_w, p, q, key, f, quantised):
    """:func:`_keep_fragment_atomic` in numba's simulator, as plain Python under a lock. The simulator's own device
    functions swap the ``cuda`` name in their globals on every call, and its threads' swaps race: one thread restored
    the real module while another was in ``cuda.atomic.max`` (a failure seen once in CI)."""
    with _SIMULATED_ATOMICS:
        best_key[p] = max(best_key[p], np.int32(key))


def _sqrt32_device(x):
    """The float32 square root on CUDA (IEEE's: numba compiles without fast maths); the simulator runs it on a NumPy
    float32, whose root it rounds once to float32 as the CPU's ``np.sqrt`` does."""
    return np.float32(math.sqrt(x))


def clone(py_func: types.FunctionType, namespace: dict) -> types.FunctionType:
    """``py_func`` with ``namespace`` as its globals: numba then resolves the names it calls there."""
    return types.FunctionType(py_func.__code__, namespace, py_func.__name__, py_func.__defaults__, py_func.__closure__)


def _block_sum_pair(sums, tid, threads, num, den):
    """Add up every thread's ``num`` and ``den`` over the block in ``sums`` (a ``(2, >= threads)`` float64 shared
    array the kernel allocates): each thread stores its pair, then a tree over the threads (``threads`` a power of
    two); on return ``sums[0, 0]`` and ``sums[1, 0]`` hold the block's totals, for every thread. It stores before its
    first barrier: a second sum into the same ``sums`` would race with threads still reading the first's totals
    (use another array, or a barrier between)."""
    sums[0, tid] = num
    sums[1, tid] = den
    syncthreads()  # noqa: F821 (bound in device_functions)
    step = threads // 2
    while step > 0:
        if tid < step:
            sums[0, tid] += sums[0, tid + step]
            sums[1, tid] += sums[1, tid + step]
        syncthreads()  # noqa: F821
        step //= 2


def _syncthreads_simulated():
    """``cuda.syncthreads`` in numba's simulator, for a plain function outside the kernel's swapped globals: the
    barrier of the simulated thread's block."""
    threading.current_thread().syncthreads()


def device_functions(functions: dict, extra: dict | None = None) -> dict:
    """Globals in which ``functions`` (plain Python, by name) are numba CUDA device functions, with ``cuda``,
    ``numba``, ``np``, ``math``, ``syncthreads`` and :func:`_block_sum_pair` (as ``block_sum_pair``) bound beside
    ``extra``; in the simulator the plain functions themselves (its device functions swap the ``cuda`` name in
    their globals on every call, and its threads' swaps race). A kernel cloned into these globals
    (:func:`clone`) calls them by name. Compiling needs no device (``numba.cuda.compile_ptx``); launching does:
    callers check :func:`cuda_unavailable_reason` first."""
    import numba
    from numba import cuda

    # stage 3's Nelder-Mead steps launch a few blocks at a time by design: no occupancy warning per launch
    numba.config.CUDA_LOW_OCCUPANCY_WARNINGS = False
    simulated = simulator_enabled()
    namespace = dict(extra or {})
    namespace.update(cuda=cuda, numba=numba, np=np, math=math,
                     syncthreads=_syncthreads_simulated if simulated else cuda.syncthreads)  # fmt: skip
    for name, py_func in {**functions, "block_sum_pair": _block_sum_pair}.items():
        namespace[name] = clone(py_func, namespace) if simulated else cuda.jit(device=True)(clone(py_func, namespace))
    return namespace


#: Low bits of an exact z-buffer key on CUDA that hold the face id (above them: 1/z's float32 bits).
FACE_ID_BITS = 32


def _keep_fragment_exact_atomic(best_key, best_w, p, q, key, f, quantised):
    """The exact z-buffer test on CUDA (the CPU's rule for packed meshes): the larger 1/z ``q`` wins, ties to the
    larger face id ``f``, as one 64-bit atomic maximum of ``q``'s float32 bits above the face id in an int64
    ``best_key`` (a non-negative float's bits order as the float; a negative or NaN 1/z never wins, as on the CPU)."""
    if q >= 0:  # + 0: a -0.0 (>= 0, wins on the CPU) gets the bits of +0.0
        bits = np.int64(float_as_int(np.float32(q) + np.float32(0.0)))  # noqa: F821 (bound in device_namespace)
        cuda.atomic.max(best_key, p, (bits << FACE_ID_BITS) | np.int64(f))  # noqa: F821


def _keep_fragment_exact_simulated(best_key, best_w, p, q, key, f, quantised):
    """:func:`_keep_fragment_exact_atomic` in numba's simulator: plain Python under the simulated atomics' lock."""
    if q >= 0:
        packed = (int((np.float32(q) + np.float32(0.0)).view(np.int32)) << FACE_ID_BITS) | int(f)
        with _SIMULATED_ATOMICS:
            best_key[p] = max(int(best_key[p]), packed)


def _scan_canvas_exact(c, tid, threads, cam_all, px_all, py_all, draw, faces, face_instance, corner_normals, R, K_inv,
                       fused, z_range, near, v0, u0, h, w, key, row):  # fmt: skip
    """Canvas ``c``'s exact z-buffer over its window (rows ``v0 ..``, columns ``u0 ..``, ``h x w``): ``key (h * w,)``
    int64 set empty (-1), then every drawn face scanned into it by the block's threads in turn, barriers after each
    step; ``row`` a 12-float local array. On return a covered pixel's key holds its face id in the low
    :data:`FACE_ID_BITS` (the CPU's ``raster_window`` with exact keys, the render of packed meshes)."""
    for p in range(tid, h * w, threads):
        key[p] = -1
    syncthreads()  # noqa: F821 (bound in device_functions)
    levels = key_levels(0, False)  # noqa: F821
    w_lo, scale = key_scale(z_range[c, 0], z_range[c, 1], near, levels)  # noqa: F821
    cam, px, py, Rc, Kc = cam_all[c], px_all[c], py_all[c], R[c], K_inv[c]
    for f in range(tid, faces.shape[0], threads):
        if draw[c, f]:
            face_row(cam, faces, face_instance, corner_normals, Rc, Kc, f, fused, row)  # noqa: F821
            qa, qb, qc = key_plane(row, False, scale, w_lo)  # noqa: F821
            scan_face(px, py, faces[f, 0], faces[f, 1], faces[f, 2], f, qa, qb, qc, v0, u0, h, w, False, levels, 0,  # noqa: F821
                      fused, key, z_range[c])  # fmt: skip
    syncthreads()  # noqa: F821


def _shade_key(c, k, i, j, v0, u0, cam_all, faces, face_instance, corner_normals, R, K_inv, fused, row):
    """``(depth, n0, n1, n2)`` at pixel ``(i, j)`` of canvas ``c``'s window (origin ``v0, u0``) whose exact key ``k``
    (>= 0) names its face, at the pixel's centre in image coordinates (the CPU's ``raster_window``)."""
    face_row(cam_all[c], faces, face_instance, corner_normals, R[c], K_inv[c], k & FACE_ID_MASK, fused, row)  # noqa: F821
    half = np.float32(0.5)
    return shade(row, np.float32(u0 + j) + half, np.float32(v0 + i) + half, fused)  # noqa: F821


#: A face id's bits in an exact key.
FACE_ID_MASK = (1 << 32) - 1


@cache
def device_namespace(exact_keys: bool = False) -> dict:
    """Globals in which the rasteriser's shared functions (and a kernel cloned into them) are numba CUDA device
    functions (:func:`device_functions`): :data:`~bop_cender.render.compiled_raster.SHARED_FUNCTIONS` by name,
    ``keep_fragment`` atomic (in the simulator, under a lock): an int32 maximum of quantised keys, or with
    ``exact_keys`` an int64 maximum of the exact keys (:data:`FACE_ID_BITS`: a face id is ``key & (2^32 - 1)``)."""
    from bop_cender.render import compiled_raster

    simulated = simulator_enabled()
    if exact_keys:
        keep = _keep_fragment_exact_simulated if simulated else _keep_fragment_exact_atomic
    else:
        keep = _keep_fragment_simulated if simulated else _keep_fragment_atomic
    functions = {**compiled_raster.SHARED_FUNCTIONS, "keep_fragment": keep, "sqrt32": _sqrt32_device}
    if exact_keys:  # a canvas's z-buffer and shading, shared by the kernels that render with exact keys
        functions.update(scan_canvas_exact=_scan_canvas_exact, shade_key=_shade_key)
    extra = {**vars(compiled_raster), "_SIMULATED_ATOMICS": _SIMULATED_ATOMICS, "FACE_ID_BITS": FACE_ID_BITS,
             "FACE_ID_MASK": FACE_ID_MASK}  # fmt: skip
    if exact_keys and not simulated:
        from numba.cuda import libdevice

        extra["float_as_int"] = libdevice.float_as_int
    return device_functions(functions, extra)
