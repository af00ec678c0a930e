"""The render-and-compare cost of pose candidates as one CUDA kernel: a thread block per (candidate, view) canvas.

Why. The torch candidate path (:mod:`bop_cender.render.candidate_curvature`) was written for the CPU's few-large-op
economy; on an H200 a cost call launched about 730 kernels and synchronised 77 times, so it cost 13-24 ms whatever
its size, and 2,000 candidates ran 14,265 calls/s against issue 11's goal of 20,000
(``results/bench/run_intel-r-xeon-r-processor-16cores-nvidia-h200.md``). Here one launch does what
:mod:`bop_cender.pose.cost_kernel` does per canvas on the CPU, with the same source for the rasteriser's steps
(:mod:`bop_cender.render.cuda_loops`):

1. the canvas's window of int32 z-buffer keys set to empty;
2. each thread scans its share of the faces into the keys (atomic maximum: the larger key wins, as on the CPU);
3. each thread shades its share of the covered pixels (the face's shading row computed again from its vertices:
   no table in memory), hides those behind placed objects, and writes their normals; the first and last window
   rows stay background (the atlas rule);
4. each thread takes the curvature and the two sums of its share of the interior pixels in float64, and the block
   adds them up.

The host waits for the device once per call, to read the windows' sizes (the scratch's size and the launches'
groups) and the nearest vertex. Quantised int32 keys only (a mesh of at most 2^15 faces,
:class:`~bop_cender.render.scanline.KeyCodec`); for larger meshes or a vertex behind the near plane
:func:`cuda_candidate_costs` returns None and the torch path runs. The ``numba`` and ``auto`` backends call it on CUDA
(:meth:`~bop_cender.pose.backend.Backend.candidate_costs`): ``auto`` takes the torch atlases, with a warning, where
numba's CUDA target does not work.

Rounding. On a GPU, NVVM contracts float32 multiply-adds into fused ones, as nvcc does for torch's CUDA kernels, so
the costs agree with the torch path's to float32 rounding, not bit for bit. In numba's CUDA simulator (CPU, no
contraction) the kernel repeats the CPU loops' arithmetic: the tests compare it with
:func:`~bop_cender.pose.cost_kernel.compiled_candidate_costs` there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np
import torch

from bop_cender.geometry.check import check_shape
from bop_cender.render.candidate_curvature import OCCLUSION_MARGIN_MM
from bop_cender.render.compiled_raster import loop_tensors
from bop_cender.render.cuda_device import DeviceFunctions, device_functions
from bop_cender.render.cuda_loops import CanvasArrays, KernelGuard, check_device, check_threads
from bop_cender.render.scanline import KeyCodec

try:  # numba's CUDA target: where it is missing, the guard says so and the torch atlases serve
    from numba import cuda
except ImportError:  # pragma: no cover
    cuda = None

#: Threads per block (one block per canvas): the float64 reduction's shared arrays have this size.
BLOCK_THREADS = 128
#: Bytes of normal-map scratch per launch (canvases beyond it go to the next launch of the call).
SCRATCH_BYTES = 1 << 30


def costs_kernel(functions: DeviceFunctions):
    """The cost kernel's Python function on ``functions`` (:func:`~bop_cender.render.cuda_device.device_functions`,
    quantised keys; ``numba.cuda.jit`` or ``numba.cuda.compile_ptx`` take it)."""
    raster, block_sum_pair = functions.raster, functions.block_sum_pair
    key_levels, key_scale, face_row, key_plane = raster.key_levels, raster.key_scale, raster.face_row, raster.key_plane
    scan_face, shade, pixel_curvature = raster.scan_face, raster.shade, raster.pixel_curvature

    def canvas_costs(canvas: CanvasArrays, face_bits, depth_bits, fused, z_range, lo, extent, blocks: LaunchBlocks,
                     near, occ, margin, dist, keys, normals, out):  # fmt: skip
        """Unweighted cost of canvas ``c = blocks.canvases[blockIdx.x]`` (view ``c % V``) into ``out[c]``:
        ``z_range (C, 2)`` its vertices' least and greatest z, ``lo, extent (C, 2)`` its window. Scratch of the
        launch's group of canvases: ``keys`` int32, block b's ``h * w`` keys from ``blocks.base[b]``; ``normals (rows,
        widest, 3)`` float32, its ``h`` rows from ``blocks.row_base[b]`` (3-D, so that the CPU's
        ``pixel_curvature`` reads it as it is)."""
        b = cuda.blockIdx.x
        c = blocks.canvases[b]
        tid = cuda.threadIdx.x
        threads = cuda.blockDim.x
        V, H, W = dist.shape[0], dist.shape[1], dist.shape[2]
        v = c % V
        top, left, h, w = lo[c, 0], lo[c, 1], extent[c, 0], extent[c, 1]
        n_pixels = h * w
        key = keys[blocks.base[b] : blocks.base[b] + n_pixels]
        nrm = normals[
            blocks.row_base[b] : blocks.row_base[b] + h
        ]  # (h, widest, 3): the window's normals in its first w columns
        levels = key_levels(depth_bits, True)
        w_lo, scale = key_scale(z_range[c, 0], z_range[c, 1], near, levels)
        for p in range(tid, n_pixels, threads):
            key[p] = -1
        cuda.syncthreads()
        row = cuda.local.array(12, numba.float32)
        cam, px, py, Rc, Kc = canvas.cam[c], canvas.px[c], canvas.py[c], canvas.R[c], canvas.K_inv[c]
        faces, face_instance, corner_normals = canvas.faces, canvas.face_instance, canvas.corner_normals
        for f in range(tid, faces.shape[0], threads):
            if canvas.draw[c, f]:
                face_row(cam, faces, face_instance, corner_normals, Rc, Kc, f, fused, row)
                qa, qb, qc = key_plane(row, True, scale, w_lo)
                scan_face(px, py, faces[f, 0], faces[f, 1], faces[f, 2], f, qa, qb, qc, top, left, h, w, True, levels,
                          face_bits, fused, key, z_range[c])  # fmt: skip
        cuda.syncthreads()
        mask = (1 << face_bits) - 1
        half = np.float32(0.5)
        for p in range(tid, n_pixels, threads):
            i = p // w
            j = p - i * w
            n0 = n1 = n2 = np.float32(0.0)
            k = key[p]
            if k >= 0 and 0 < i < h - 1:  # the first and last rows of a window are background (the atlas rule)
                face_row(cam, faces, face_instance, corner_normals, Rc, Kc, k & mask, fused, row)
                depth, n0, n1, n2 = shade(row, np.float32(left + j) + half, np.float32(top + i) + half, fused)
                r, s = top + i, left + j
                if occ.shape[0] > 0 and 0 <= r < H and 0 <= s < W:  # candidate_curvature.occluded
                    o = occ[v, r, s]
                    if o > 0 and depth > 0 and depth > o - margin:
                        n0 = n1 = n2 = np.float32(0.0)
            nrm[i, j, 0] = n0
            nrm[i, j, 1] = n1
            nrm[i, j, 2] = n2
        cuda.syncthreads()
        num = 0.0
        den = 0.0
        for p in range(tid, n_pixels, threads):
            i = p // w
            j = p - i * w
            r, s = top + i, left + j
            if 0 < i < h - 1 and 0 < j < w - 1 and 0 <= r < H and 0 <= s < W:
                curv = pixel_curvature(nrm, i - 1, i, i + 1, j - 1, j, j + 1, fused)
                num += np.float64(curv) * np.float64(dist[v, r, s])
                den += np.float64(curv)
        sums = cuda.shared.array((2, BLOCK_THREADS), numba.float64)
        block_sum_pair(sums, tid, threads, num, den)
        if tid == 0:
            out[c] = (
                np.float32(sums[0, 0] / sums[1, 0])
                if sums[1, 0] > 0.0
                else np.float32(math.hypot(np.float64(H), np.float64(W)))
            )

    return canvas_costs


def kernel_function():
    """The kernel's Python function on this process's device functions (not compiled yet:
    ``scripts/check_cuda_compile.py`` compiles it to PTX)."""
    return costs_kernel(device_functions())


class LaunchBlocks(NamedTuple):
    """Which canvas each block of a launch takes (``canvases (n,)`` int64) and where its scratch starts: its first key
    (``base``) and its first normal-map row (``row_base``), both ``(n,)`` int64."""

    canvases: torch.Tensor
    base: torch.Tensor
    row_base: torch.Tensor


#: The kernel's standing in this process (compiled on first use; where it cannot run, the torch atlases).
GUARD = KernelGuard("the CUDA cost kernel", "the render cost runs on the torch atlases on CUDA", kernel_function)


def cuda_candidate_costs(mesh, T_cam_model: torch.Tensor, K: torch.Tensor, height: int, width: int, near: float,
                         dist_maps: torch.Tensor, occluder_depth: torch.Tensor | None = None,
                         threads: int = BLOCK_THREADS, fused: bool = True,
                         scratch_bytes: int = SCRATCH_BYTES) -> torch.Tensor | None:  # fmt: skip
    """Unweighted costs ``(B * V,)`` float32 of B candidates in V views (canvas ``c`` = candidate ``c // V`` in view
    ``c % V``), as :meth:`~bop_cender.pose.backend.Backend.candidate_costs` takes them per view, by the CUDA kernel; None where
    it does not apply (a mesh of more than 2^15 faces, whose keys are exact; a vertex behind the near plane: use the
    torch path).

    Args:
        mesh, T_cam_model, K, height, width, near, dist_maps, occluder_depth, scratch_bytes: as :func:`launch_plan`,
            the tensors on a CUDA device (or the CPU under numba's CUDA simulator).
        threads: threads per block, a power of two up to :data:`BLOCK_THREADS` (the tests use fewer: the simulator
            runs each thread as a Python thread).
        fused: multiply-adds rounded once (the GPU's torch; the CPU loops take torch's CPU rounding as probed).
    """
    check_threads(threads, BLOCK_THREADS)
    device = T_cam_model.device
    check_device(device, "the CUDA cost kernel")
    plan = launch_plan(mesh, T_cam_model, K, height, width, near, dist_maps, occluder_depth, fused, scratch_bytes)
    if plan is None or not plan.launches:
        return plan if plan is None else plan.out
    for blocks, arguments in plan.launches:  # in stream order: each launch reuses the scratch
        GUARD.launch(blocks, threads, arguments, device)
    return plan.out


@dataclass(frozen=True)
class LaunchPlan:
    """The kernel's launches of one call: ``(blocks, arguments)`` each, the arguments in the kernel's order (tensors
    and scalars), and ``out (C,)``, which they fill."""

    out: torch.Tensor
    launches: list[tuple[int, list]]


def launch_plan(mesh, T_cam_model: torch.Tensor, K: torch.Tensor, height: int, width: int, near: float,
                dist_maps: torch.Tensor, occluder_depth: torch.Tensor | None = None, fused: bool = True,
                scratch_bytes: int = SCRATCH_BYTES) -> LaunchPlan | None:  # fmt: skip
    """The kernel's inputs, scratch and launches for B candidates in V views, on the inputs' device (no launch); None
    where the kernel does not apply.

    The windows' sizes and the nearest vertex are read back once (the call's one wait for the device); canvases are
    launched in groups, by window width, whose normal maps fit ``scratch_bytes`` (a batch of 2,000 candidates in six
    320x256 views takes one or two launches).

    Args:
        mesh: the object (:class:`~bop_cender.render.mesh.RenderMesh` on the inputs' device).
        T_cam_model: ``(B, V, 4, 4)`` float32 candidate poses in each view's camera frame (mm).
        K: ``(V, 3, 3)`` float32 intrinsics; height, width: image size; near: near plane (mm).
        dist_maps: ``(V, H, W)`` float32 distance maps.
        occluder_depth: ``(V, H, W)`` float32 depth of the objects already placed (0: none), or None.
        fused: multiply-adds rounded once.
        scratch_bytes: bytes of normal maps per launch (at least one canvas per launch).
    """
    from bop_cender.render.candidate_curvature import window_bounds

    device = T_cam_model.device
    sizes = check_shape(T_cam_model, "B V 4 4", "T_cam_model")
    check_shape(K, "V 3 3", "K", sizes)
    check_shape(dist_maps, f"V {int(height)} {int(width)}", "dist_maps", sizes)
    if occluder_depth is not None:
        check_shape(occluder_depth, f"V {int(height)} {int(width)}", "occluder_depth", sizes)
    if KeyCodec.for_faces(int(mesh.faces.shape[0])).dtype != torch.int32:
        return None  # exact keys: the torch path
    B, V = int(T_cam_model.shape[0]), int(T_cam_model.shape[1])
    C = B * V
    out = torch.empty(C, dtype=torch.float32, device=device)
    if C == 0:
        return LaunchPlan(out, [])
    T = T_cam_model.reshape(C, 4, 4)
    R, t = T[:, :3, :3], T[:, :3, 3]
    Kc = K.index_select(0, torch.arange(C, device=device) % V)
    inputs = loop_tensors(mesh, R[:, None].contiguous(), t[:, None].contiguous(), Kc, near, check_near=False)
    cam = inputs[0]
    lo, hi = window_bounds(cam.permute(2, 0, 1), Kc, height, width)
    extent = hi - lo
    z_range = torch.stack([cam[..., 2].amin(1), cam[..., 2].amax(1)], 1).contiguous()
    read = torch.cat([extent.reshape(-1).double(), z_range[:, 0].amin().reshape(1).double()]).cpu().numpy()  # a wait
    if read[-1] < near:
        return None  # a vertex behind the near plane: the torch renderer clips it
    groups = _launch_groups(read[:-1].astype(np.int64).reshape(C, 2), scratch_bytes)
    occ = torch.zeros((0, 1, 1), dtype=torch.float32, device=device) if occluder_depth is None else occluder_depth
    keys = torch.empty(max(g.pixels for g in groups), dtype=torch.int32, device=device)
    normals = torch.empty(max(g.rows * g.widest * 3 for g in groups), dtype=torch.float32, device=device)
    # every group's block table in one copy, before any launch (a copy from pageable memory waits for the stream)
    tables = torch.from_numpy(np.concatenate([np.stack([g.canvases, g.base, g.row_base]) for g in groups], 1))
    tables = tables.to(device)
    launches, first = [], 0
    for group in groups:
        n = len(group.canvases)
        scratch = normals[: group.rows * group.widest * 3].view(group.rows, group.widest, 3)
        blocks = LaunchBlocks(*tables[:, first : first + n])
        launches.append((n, [CanvasArrays.of(inputs), *inputs[-2:], bool(fused), z_range, lo.contiguous(),
                             extent.contiguous(), blocks, np.float32(near), occ.float().contiguous(),
                             np.float32(OCCLUSION_MARGIN_MM), dist_maps.float().contiguous(), keys, scratch, out]))  # fmt: skip
        first += n
    return LaunchPlan(out, launches)


@dataclass(frozen=True)
class _Group:
    """Canvases launched together: their ids, each one's first key and first normal-map row in the scratch."""

    canvases: np.ndarray
    base: np.ndarray
    row_base: np.ndarray
    pixels: int
    rows: int
    widest: int


def _launch_groups(extent: np.ndarray, scratch_bytes: int) -> list[_Group]:
    """Canvases by window width (``extent (C, 2)``: rows, columns), cut into groups whose normal maps (rows x the
    group's widest row x 3 float32) fit ``scratch_bytes``, at least one canvas each. Vectorised per group (a batch
    of 2,000 candidates in six views is 12,000 canvases, and this runs on every call)."""
    order = np.argsort(extent[:, 1], kind="stable")
    widths = extent[order, 1]
    rows_before = np.concatenate([[0], np.cumsum(extent[order, 0])])
    groups, start = [], 0
    while start < len(order):
        # sorted by width: a group from `start` to n has normal maps of (rows) x widths[n - 1] x 12 bytes, growing in n
        fits = (rows_before[start + 1 :] - rows_before[start]) * widths[start:] * 12 <= scratch_bytes
        stop = start + max(1, int(np.count_nonzero(fits)))
        groups.append(_group(extent, order[start:stop]))
        start = stop
    return groups


def _group(extent: np.ndarray, canvases: np.ndarray) -> _Group:
    heights = extent[canvases, 0]
    pixels = heights * extent[canvases, 1]
    return _Group(canvases.astype(np.int64), np.cumsum(pixels) - pixels, np.cumsum(heights) - heights,
                  int(pixels.sum()), int(heights.sum()), int(extent[canvases, 1].max()))  # fmt: skip
