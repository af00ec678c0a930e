"""How a CUDA kernel runs in this process: whether numba's CUDA target works here, its guard, its launch.

Why. On a GPU the torch renderer's candidate path launches about 730 kernels and synchronises 77 times per cost
call (``results/bench/run_*nvidia-h200.md``), so a call costs 13-24 ms whatever its size. Stage 3's costs and the
renderer therefore have a CUDA kernel each (:mod:`bop_cender.pose.cuda_cost`, :mod:`bop_cender.pose.cuda_edge_kernel`,
:mod:`bop_cender.pose.cuda_window_kernel`, :mod:`bop_cender.render.cuda_render`), built from the CPU loops' own
arithmetic (:mod:`bop_cender.render.cuda_device`). What they share at run time is here: :class:`KernelGuard` (compile
on first use, launch on torch's stream, and tell the caller when to take its torch path instead), the checks of a
launch, and :class:`CanvasArrays`, the rasteriser's inputs as the kernels take them.

numba's CUDA target is optional: it needs ``numba.cuda`` with a driver (``pip install numba-cuda``, present in
the NVIDIA images we benchmark on) or numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``), where the kernels run as
Python threads on the CPU: how the tests check them against the CPU loops on machines without a GPU. Nothing here
imports ``numba.cuda`` before it is asked whether it works.
"""

from __future__ import annotations

import functools
import re
import warnings
from collections.abc import Callable
from functools import cache
from typing import NamedTuple, TypeVar

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
        build: returns the kernel's Python function (a kernel factory's result, :mod:`bop_cender.render.cuda_device`),
            which ``numba.cuda.jit`` compiles; called on first use only.
    """

    def __init__(self, name: str, fallback: str, build: Callable[[], Callable]) -> None:
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

    def run(self, compute: Callable[[], T_out | None], insist: bool = False) -> T_out | None:
        """``compute()`` (a call of the kernel) where it can run; None where the caller's torch path is to serve:
        ``compute`` returned None (the kernel does not apply), or, unless ``insist``, the kernel is unavailable or
        failed (warned once).

        Raises:
            RuntimeError: with ``insist`` (the backend named ``numba``, :mod:`bop_cender.render.backend`), where the
                kernel is unavailable; the kernel's own error where it failed.
        """
        reason = self.unavailable()
        if reason is not None:
            if insist:
                hint = " (pip install numba-cuda)" if cuda_unavailable_reason() else ""
                raise RuntimeError(f"this call needs {self.name}, which cannot run here: {reason}{hint}")
            self.warn_once(f"{self.fallback}: {reason}")
            return None
        try:
            return compute()
        except Exception as error:  # the torch path stays available
            if insist:
                raise
            if is_kernel_error(error):  # numba's compilation, the driver or the launch: for the rest of the process
                self.note_failure(error)
            else:  # e.g. out of memory for this call's scratch: this call only
                message = f"{self.fallback} for a call: {self.name}'s call failed ({_described(error)})"
                self.warn_once(message, key=f"call failed: {type(error).__name__}")  # once per kind, not per size
            return None

    def launch(self, blocks: int, threads: int, arguments: list, device: torch.device) -> None:
        """Launch the kernel on ``blocks`` blocks of ``threads`` threads with ``arguments`` (tensors, as CUDA arrays
        on torch's current stream of ``device``; named tuples of tensors, such as :class:`CanvasArrays`, field by
        field; scalars as they are); in numba's simulator on the tensors' NumPy views."""
        if simulator_enabled():  # numba's simulator runs the kernel on NumPy arrays
            self.kernel[blocks, threads](*(_converted(x, lambda t: t.detach().numpy()) for x in arguments))
            return
        from numba import cuda

        with cuda.gpus[device.index if device.index is not None else torch.cuda.current_device()]:
            # the arrays and the stream inside the device's context: on cuda:1 they would otherwise bind device 0's
            arrays = [_converted(x, lambda t: cuda.as_cuda_array(t.detach())) for x in arguments]
            stream = cuda.external_stream(torch.cuda.current_stream(device).cuda_stream)
            self.kernel[blocks, threads, stream](*arrays)


def _converted(argument, array: Callable):
    """A kernel argument with its tensors passed through ``array``: a tensor, the fields of a named tuple (numba
    passes a tuple's fields as arguments of their own), or a scalar as it is."""
    if isinstance(argument, torch.Tensor):
        return array(argument)
    if isinstance(argument, tuple):
        return type(argument)(*(_converted(x, array) for x in argument))
    return argument


class CanvasArrays(NamedTuple):
    """What the rasteriser reads of C canvases, as the CUDA kernels take it (one argument; the CPU loops take the
    same arrays one by one): :func:`~bop_cender.render.compiled_raster.loop_tensors`' first nine, on one device.

    Attributes:
        cam: ``(C, N, 3)`` float32 camera-space vertices (mm).
        px, py: ``(C, N)`` float32 their projections (pixels).
        draw: ``(C, F)`` bool faces drawn (front-facing).
        faces: ``(F, 3)`` int64 vertex ids; face_instance: ``(F,)`` int64 the instance whose rotation turns its
            normals; corner_normals: ``(F, 3, 3)`` float32 model frame.
        R: ``(C, I, 3, 3)`` float32 model-to-camera rotations; K_inv: ``(C, 9)`` float32 inverse intrinsics.
    """

    cam: torch.Tensor
    px: torch.Tensor
    py: torch.Tensor
    draw: torch.Tensor
    faces: torch.Tensor
    face_instance: torch.Tensor
    corner_normals: torch.Tensor
    R: torch.Tensor
    K_inv: torch.Tensor

    @staticmethod
    def of(tensors: tuple) -> CanvasArrays:
        """The first nine of :func:`~bop_cender.render.compiled_raster.loop_tensors`' tensors, contiguous."""
        return CanvasArrays(*(x.contiguous() for x in tensors[:9]))


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
) -> tuple[tuple[CanvasArrays, bool, torch.Tensor], torch.Tensor]:
    """What the exact-key kernels (the renderer's and the scene costs') read of C canvases of packed meshes: the
    :class:`CanvasArrays`, the multiply-add rounding
    (fused on a GPU, as torch's CUDA kernels round; in numba's simulator the CPU's as probed, so that it repeats the
    CPU loops' bits), the canvases' vertex depth range ``z_range (C, 2)``; and, apart, the least vertex depth (a 0-d
    tensor, read back with the call's results: a vertex behind the near plane leaves the call to the torch path).
    Packed meshes know their vertex counts: nothing here waits for the device."""
    from bop_cender.render.compiled_raster import ADDCMUL_FUSED, loop_tensors

    inputs = loop_tensors(packed, R, t, K, near, check_near=False)
    z = inputs[0][..., 2]  # (C, N) camera-space vertex depths
    z_range = torch.stack([z.amin(1), z.amax(1)], 1).contiguous()
    fused = bool(ADDCMUL_FUSED) if simulator_enabled() else True
    return (CanvasArrays.of(inputs), fused, z_range), z_range[:, 0].amin()
