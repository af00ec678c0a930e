"""The renderer on CUDA as one kernel: depth, normals and face ids of packed meshes, a thread block per canvas.

Why. :func:`~bop_cender.render.rasterizer.render_scene` runs the torch pipeline on CUDA: about 2,000 operators a
call whatever its size, so that a render of a few parts in seven views costs about 20 ms on an H200, launch bound
(``results/bench/run_*nvidia-h200.md``: the full scene cost, a render and a few steps, 19 ms). Stage 3 renders the
placed parts as occluders of every object it searches, and the scene polish renders each part's neighbours into its
windows: on CUDA those renders are the last torch pipeline left in a search's loop. Here a call is one launch,
block ``c`` drawing canvas ``c`` as the CPU's compiled loop does (:func:`~bop_cender.render.compiled_raster.
raster_window` with exact keys: 1/z, ties to the larger face id), with its source
(:mod:`bop_cender.render.cuda_device`): the window's z-buffer as 64-bit atomic maxima, then the
covered pixels shaded at their centres.

Rounding. On a GPU NVVM contracts float32 multiply-adds, as nvcc does for torch's CUDA kernels: the maps agree with
the CPU's to float32 rounding, and a pixel where two faces' depths are within that rounding may show the other face.
In numba's CUDA simulator (the tests, without a GPU) the device functions are the CPU's plain Python ones and the
maps are the CPU's bit for bit.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

from bop_cender.render.cuda_device import FACE_ID_MASK, DeviceFunctions, device_functions
from bop_cender.render.cuda_loops import CanvasArrays, KernelGuard, check_device, check_threads, exact_key_inputs
from bop_cender.render.mesh import PackedMeshes

try:  # numba's CUDA target: where it is missing, the guard says so and render_scene takes the torch pipeline
    from numba import cuda
except ImportError:  # pragma: no cover
    cuda = None

#: Most threads per block (one block per canvas).
BLOCK_THREADS = 512
#: Threads per block by default: a window of the scene polish (about 100 x 100 pixels) gets the fewer, a full frame
#: (the occluder depth: one block per view for 82,000-389,000 pixels each) the more.
WINDOW_THREADS, FRAME_THREADS = 128, 512
#: Pixels of canvases per launch (their z-buffer scratch: 8 bytes a pixel, so 256 MiB).
CHUNK_PIXELS = 1 << 25


def render_kernel(functions: DeviceFunctions):
    """The render kernel's Python function on ``functions`` (:func:`~bop_cender.render.cuda_device.device_functions`
    with exact keys; ``numba.cuda.jit`` or ``numba.cuda.compile_ptx`` take it)."""
    scan_canvas_exact, shade_key = functions.scan_canvas_exact, functions.shade_key

    def render_canvases(canvas: CanvasArrays, fused, z_range, near, offsets, keys, depth, normals, face_map):
        """Canvas ``c = blockIdx.x`` into ``depth[c] (h, w)``, ``normals[c] (h, w, 3)`` and ``face_map[c] (h, w)`` (0,
        0 and -1 where nothing is drawn), its window at ``offsets[c]`` (row, column); ``z_range (C, 2)`` the canvas's
        least and greatest vertex z; scratch ``keys (C, h * w)`` int64."""
        c = cuda.blockIdx.x
        tid = cuda.threadIdx.x
        threads = cuda.blockDim.x
        h, w = depth.shape[1], depth.shape[2]
        v0, u0 = offsets[c, 0], offsets[c, 1]
        key = keys[c]
        row = cuda.local.array(12, numba.float32)
        scan_canvas_exact(c, tid, threads, canvas, fused, z_range, near, v0, u0, h, w, key, row)
        zero = np.float32(0.0)
        for p in range(tid, h * w, threads):
            i = p // w
            j = p - i * w
            k = key[p]
            d = n0 = n1 = n2 = zero
            f = -1
            if k >= 0:
                d, n0, n1, n2 = shade_key(c, k, i, j, v0, u0, canvas, fused, row)
                f = k & FACE_ID_MASK
            depth[c, i, j] = d
            normals[c, i, j, 0] = n0
            normals[c, i, j, 1] = n1
            normals[c, i, j, 2] = n2
            face_map[c, i, j] = f

    return render_canvases


def kernel_function():
    """The kernel's Python function on this process's device functions (not compiled yet:
    ``scripts/check_cuda_compile.py`` compiles it to PTX)."""
    return render_kernel(device_functions(exact_keys=True))


#: The kernel's standing in this process (compiled on first use; where it cannot run, the torch pipeline).
GUARD = KernelGuard("the CUDA render kernel", "render_scene runs the torch pipeline on CUDA", kernel_function)


def cuda_render(packed: PackedMeshes, R: torch.Tensor, t: torch.Tensor, K: torch.Tensor, height: int, width: int,
                near: float, offsets: torch.Tensor | None = None,
                threads: int | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None:  # fmt: skip
    """Depth ``(C, H, W)`` (z in mm, 0 on background), unit normals ``(C, H, W, 3)`` and face ids ``(C, H, W)`` int64
    (packed index, -1 on background) of packed meshes in C canvases, as the CPU's
    :func:`~bop_cender.render.compiled_raster.render_compiled` gives them; None where a vertex lies behind the near
    plane in some canvas (the torch renderer cuts the faces there: use it).

    Args:
        packed: the meshes (on the inputs' device; ``vertex_counts`` known, or counting them waits for the device).
        R: ``(C, I, 3, 3)`` float32 model-to-camera rotations of the I instances, ``t``: ``(C, I, 3)`` (mm).
        K: ``(C, 3, 3)`` float32 intrinsics; height, width: the canvas size; near: the near plane (mm).
        offsets: ``(C, 2)`` int64 each canvas's window origin (row, column) in its image; None: the full frame.
        threads: threads per block, a power of two up to :data:`BLOCK_THREADS` (None: :data:`FRAME_THREADS` for
            canvases of more than 128 x 128 pixels, else :data:`WINDOW_THREADS`; the tests use fewer: the simulator
            runs each thread as a Python thread).

    Raises:
        ValueError: ``threads`` out of range, or CPU tensors outside the simulator.
    """
    if threads is None:
        threads = FRAME_THREADS if height * width > 128 * 128 else WINDOW_THREADS
    check_threads(threads, BLOCK_THREADS)
    device = R.device
    check_device(device, "the CUDA render kernel")
    C = int(R.shape[0])
    depth = torch.empty((C, height, width), dtype=torch.float32, device=device)
    normals = torch.empty((C, height, width, 3), dtype=torch.float32, device=device)
    face_map = torch.empty((C, height, width), dtype=torch.int64, device=device)
    if C == 0 or packed.vertices.shape[0] == 0:  # nothing to draw: the background
        depth.zero_()
        normals.zero_()
        face_map.fill_(-1)
        return depth, normals, face_map
    origins = torch.zeros((C, 2), dtype=torch.int64, device=device) if offsets is None else offsets.to(torch.int64)
    chunk = max(1, CHUNK_PIXELS // max(1, height * width))
    keys = torch.empty((min(C, chunk), height * width), dtype=torch.int64, device=device)
    z_lows = []
    for start in range(0, C, chunk):  # canvases in chunks: the z-buffer's scratch stays bounded (the maps are whole)
        rows = slice(start, min(C, start + chunk))
        canvases, z_low = exact_key_inputs(packed, R[rows], t[rows], K[rows], near)
        z_lows.append(z_low)
        arguments = [*canvases, np.float32(near), origins[rows].contiguous(), keys, depth[rows], normals[rows],
                     face_map[rows]]  # fmt: skip
        GUARD.launch(rows.stop - rows.start, threads, arguments, device)
    if float(torch.stack(z_lows).amin()) < near:  # the call's one wait for the device
        return None
    return depth, normals, face_map
