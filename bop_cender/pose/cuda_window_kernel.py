"""The scene polish's windowed cost (and the full scene cost) as one CUDA kernel: a thread block per window.

Why. The scene polish (:mod:`bop_cender.pose.scene_polish`) costs one to seven trial poses of one part per Nelder-Mead
step, about a hundred steps per part and pass. On CUDA it ran the torch steps (render, composite, curvature, both
terms): 15 ms a call on an H200 whatever its size (``results/bench/run_*nvidia-h200.md``, "Scene polish"), launch
bound, so that the polish alone would take about 15 s of a scene against issue 11's goal of 2 s. Here a call is one
launch. Block ``c`` takes canvas ``c`` (trial ``c // V`` in view ``c % V``) and does what the CPU does per canvas
(the compiled render of :mod:`bop_cender.render.compiled_raster`, then :mod:`bop_cender.pose.window_kernel`):

1. scans the part's drawn faces into the window's z-buffer with the CPU's exact keys (1/z, ties to the larger face
   id: the render of one packed mesh), as 64-bit atomic maxima of 1/z's float bits and the face id;
2. shades the covered pixels and composites them over the other parts by depth;
3. takes the curvature of the composite (replicated border) and the forward sums in float64, and marks the
   composite's own edges (curvature above the threshold);
4. the backward term, the mean over the window's target edges of the distance to the nearest own edge: the exact
   Euclidean distance, by rows (each row's distance to its nearest own edge, one thread a row) and then, at each
   target pixel only, the least ``g(k, j)^2 + (i - k)^2`` over the rows ``k`` (the CPU loop's own functions,
   :mod:`bop_cender.pose.window_kernel`): the exact distance, without a transform of the window.

The same kernel gives the full scene cost (:meth:`~bop_cender.pose.backend.Backend.scene_cost`, the sweeps' judge and the
polish's acceptance: 19 ms a call in torch on the H200): every placed part in every full frame, each view one window
with nothing else in it (:func:`cuda_scene_cost`).

The host waits once per call, for the costs and the nearest vertex together; where a vertex lies behind the near
plane the costs are dropped and the torch steps run (the torch renderer cuts the faces there).

Rounding. On a GPU NVVM contracts float32 multiply-adds, so the costs agree with the CPU's to float32 rounding. In
numba's CUDA simulator (the tests, without a GPU) the device functions are the CPU's plain Python ones and the
costs repeat the CPU's but for the order of the float64 sums.
"""

from __future__ import annotations

import math
from functools import cache

import numba
import numpy as np
import torch

from bop_cender.pose.scene_polish import SceneWindow
from bop_cender.pose.window_kernel import DistanceArithmetic, distance_arithmetic
from bop_cender.render.cuda_device import DeviceFunctions, device_functions
from bop_cender.render.cuda_loops import (
    CanvasArrays,
    KernelGuard,
    check_device,
    check_threads,
    exact_key_inputs,
    simulator_enabled,
)
from bop_cender.render.mesh import PackedMeshes, RenderMesh, pack_meshes
from bop_cender.render.raster import DEFAULT_NEAR

try:  # numba's CUDA target: where it is missing, the guard says so and the scene costs take their torch steps
    from numba import cuda
except ImportError:  # pragma: no cover
    cuda = None

#: Most threads per block (one block per window); a power of two, the size of the float64 reductions' shared arrays.
BLOCK_THREADS = 512
#: Threads per block of a scene polish window (about 100 x 100 pixels, 7 to 49 windows a call).
WINDOW_THREADS = 128
#: Threads per block of a full frame (the scene cost: one block per view, 7 blocks for 82,000-389,000 pixels each).
FRAME_THREADS = 512


def window_kernel(functions: DeviceFunctions, distances: DistanceArithmetic):
    """The window kernel's Python function on ``functions`` (:func:`~bop_cender.render.cuda_device.device_functions`
    with exact keys) and the backward term's ``distances`` (:func:`~bop_cender.pose.window_kernel.distance_arithmetic`,
    the CPU loop's own source) compiled for the same target; ``numba.cuda.jit`` or ``numba.cuda.compile_ptx`` take
    it."""
    scan_canvas_exact, shade_key, block_sum_pair = (
        functions.scan_canvas_exact,
        functions.shade_key,
        functions.block_sum_pair,
    )
    pixel_curvature, sqrt32 = functions.raster.pixel_curvature, functions.raster.sqrt32
    row_distances, nearest_edge_sq = distances.row_distances, distances.nearest_edge_sq

    def window_costs(canvas: CanvasArrays, fused, z_range, near, other_depth, other_normals, dist, offsets,
                     target_edges, threshold, keys, comp, out):  # fmt: skip
        """``out[c]`` = forward plus backward cost of canvas ``c = blockIdx.x`` (view ``c % V``): ``z_range (C, 2)``
        the canvas's least and greatest vertex z; ``other_depth (V, h, w)`` and ``other_normals (V, h, w, 3)`` the
        other parts (no rows: none); ``dist (V, H, W)``; ``offsets (V, 2)`` each window's origin (row, column);
        ``target_edges (V, h, w)`` uint8; scratch ``keys (C, h * w)`` int64 and ``comp (C, h, w, 3)`` float32."""
        c = cuda.blockIdx.x
        tid = cuda.threadIdx.x
        threads = cuda.blockDim.x
        V, H, W = dist.shape[0], dist.shape[1], dist.shape[2]
        h, w = comp.shape[1], comp.shape[2]
        v = c % V
        n_pixels = h * w
        key = keys[c]
        nrm = comp[c]
        row = cuda.local.array(12, numba.float32)
        # 1. the z-buffer: exact keys (the CPU's rule for packed meshes)
        scan_canvas_exact(c, tid, threads, canvas, fused, z_range, near, 0, 0, h, w, key, row)
        # 2. shade and composite over the other parts (window_kernel._composite_costs)
        has_other = other_depth.shape[0] > 0
        zero = np.float32(0.0)
        for p in range(tid, n_pixels, threads):
            i = p // w
            j = p - i * w
            d = zero
            n0 = n1 = n2 = zero
            k = key[p]
            if k >= 0:
                d, n0, n1, n2 = shade_key(c, k, i, j, 0, 0, canvas, fused, row)
            o = other_depth[v, i, j] if has_other else zero
            if not (d > 0 and (o == 0 or d < o)):
                n0 = other_normals[v, i, j, 0] if has_other else zero
                n1 = other_normals[v, i, j, 1] if has_other else zero
                n2 = other_normals[v, i, j, 2] if has_other else zero
            nrm[i, j, 0] = n0
            nrm[i, j, 1] = n1
            nrm[i, j, 2] = n2
        cuda.syncthreads()
        # 3. curvature, forward sums, own edges (the key array now holds 0 at an own edge, `far` elsewhere)
        top, left = offsets[v, 0], offsets[v, 1]
        far = 2 * (h + w)
        num = 0.0
        den = 0.0
        own = 0.0
        for p in range(tid, n_pixels, threads):
            i = p // w
            j = p - i * w
            curv = pixel_curvature(nrm, max(i - 1, 0), i, min(i + 1, h - 1), max(j - 1, 0), j, min(j + 1, w - 1), fused)
            r, s = top + i, left + j
            if 0 <= r < H and 0 <= s < W:
                num += np.float64(curv) * np.float64(dist[v, r, s])
                den += np.float64(curv)
            if curv > threshold:
                key[p] = 0
                own += 1.0
            else:
                key[p] = far
        sums = cuda.shared.array((2, BLOCK_THREADS), numba.float64)
        block_sum_pair(sums, tid, threads, num, den)
        forward = sums[0, 0] / sums[1, 0] if sums[1, 0] > 0.0 else math.hypot(np.float64(H), np.float64(W))
        counts = cuda.shared.array((2, BLOCK_THREADS), numba.float64)
        block_sum_pair(counts, tid, threads, own, 0.0)  # also the barrier before the rows
        own_edges = counts[0, 0]
        # 4a. each row's distance to its nearest own edge (`far` where the row has none)
        for i in range(tid, h, threads):
            row_distances(key, i * w, w)
        cuda.syncthreads()
        # 4b. at each target edge, the nearest own edge over the rows
        total = 0.0
        targets = 0.0
        for p in range(tid, n_pixels, threads):
            i = p // w
            j = p - i * w
            if target_edges[v, i, j] != 0:
                targets += 1.0
                if own_edges > 0.0:
                    total += np.float64(sqrt32(np.float32(nearest_edge_sq(key, i, j, h, w, far))))
        sums2 = cuda.shared.array((2, BLOCK_THREADS), numba.float64)
        block_sum_pair(sums2, tid, threads, total, targets)
        if tid == 0:
            backward = 0.0
            if sums2[1, 0] > 0.0:
                backward = sums2[0, 0] / sums2[1, 0] if own_edges > 0.0 else np.float64(np.float32(math.hypot(h, w)))
            out[c] = forward + backward

    return window_costs


@cache
def _distances() -> DistanceArithmetic:
    """The backward term's distances as this process's CUDA device functions (plain in numba's simulator)."""
    return distance_arithmetic((lambda f: f) if simulator_enabled() else cuda.jit(device=True))


def kernel_function():
    """The kernel's Python function on this process's device functions (not compiled yet:
    ``scripts/check_cuda_compile.py`` compiles it to PTX)."""
    return window_kernel(device_functions(exact_keys=True), _distances())


#: The kernel's standing in this process (compiled on first use; where it cannot run, the callers' torch steps).
GUARD = KernelGuard("the CUDA window kernel", "the scene costs run their torch steps on CUDA", kernel_function)


def cuda_window_costs(
    window: SceneWindow, T_world_model: np.ndarray, threads: int = WINDOW_THREADS
) -> np.ndarray | None:
    """``(m,)`` windowed scene costs of trial poses ``T_world_model (m, 4, 4)`` of the window's part, as
    :meth:`~bop_cender.pose.backend.Backend.window_costs` gives them on the CPU, by the CUDA kernel; None where a
    vertex lies behind the near plane in some canvas (use the torch steps, whose renderer cuts the faces there).

    Args:
        window: the part's :class:`~bop_cender.pose.scene_polish.SceneWindow`, its tensors on a CUDA device (or the
            CPU under numba's CUDA simulator).
        T_world_model: the trial poses (mm).
        threads: threads per block, a power of two up to :data:`BLOCK_THREADS` (the tests use fewer: the simulator
            runs each thread as a Python thread).

    Raises:
        ValueError: ``threads`` out of range, or CPU tensors outside the simulator.
    """
    m, V = len(T_world_model), len(window.T_cam_world)
    if m == 0 or V == 0:
        _check_launch(window.dist.device, threads)
        return np.zeros(m) if V else None  # no view: the torch steps say what that costs
    costs = canvas_costs(*window_canvases(window, T_world_model), threads)
    return None if costs is None else costs.reshape(m, V).mean(1)


def window_canvases(window: SceneWindow, T_world_model: np.ndarray) -> tuple:
    """:func:`canvas_costs`' arguments (before ``threads``) for trial poses ``T_world_model (m, 4, 4)`` of a window's
    part: canvas ``c`` = trial ``c // V`` in view ``c % V``, the part as packed meshes as the CPU renders it (exact
    keys, the packed culling)."""
    device = window.dist.device
    m, V = len(T_world_model), len(window.T_cam_world)
    T_cm = np.einsum("vij,mjk->mvik", window.T_cam_world, T_world_model).reshape(m * V, 1, 4, 4)
    T = torch.as_tensor(T_cm, dtype=torch.float32, device=device)
    packed = window.packed if window.packed is not None else pack_meshes([window.mesh.to(device)])
    other = (window.other_depth, window.other_normals) if window.other_depth.shape[0] > 0 else (None, None)
    return (packed, T[..., :3, :3], T[..., :3, 3], window.K.repeat(m, 1, 1), window.size, window.offsets, *other,
            window.dist, window.target_edges, window.edge_threshold)  # fmt: skip


def cuda_scene_cost(
    meshes: list[RenderMesh],
    T_cam_model: torch.Tensor,
    K: torch.Tensor,
    target_edges: torch.Tensor,
    dist_maps: torch.Tensor,
    edge_threshold: float,
    threads: int = FRAME_THREADS,
) -> float | None:
    """The full scene cost (:meth:`~bop_cender.pose.backend.Backend.scene_cost`: every placed part rendered into every full
    frame, forward plus backward, the mean over the views) by the same kernel, each view one canvas, the frame its
    window, nothing else in it; None where a vertex lies behind the near plane (use the torch steps).

    Args:
        meshes, T_cam_model ``(V, M, 4, 4)``, K ``(V, 3, 3)``, target_edges ``(V, H, W)``, dist_maps ``(V, H, W)``,
            edge_threshold: as ``scene_cost``, the tensors on a CUDA device (or the CPU under the simulator).
        threads: as :func:`cuda_window_costs`.
    """
    device = dist_maps.device
    V, H, W = (int(x) for x in target_edges.shape)
    if V == 0 or not meshes:
        _check_launch(device, threads)
        return None  # nothing to launch: the torch steps say what such a placement costs
    T = T_cam_model.to(device, torch.float32)
    costs = canvas_costs(
        pack_meshes([mesh.to(device) for mesh in meshes]), T[..., :3, :3], T[..., :3, 3], K.to(device, torch.float32),
        (H, W), torch.zeros((V, 2), dtype=torch.int64, device=device), None, None, dist_maps.to(device),
        target_edges.to(device), edge_threshold, threads,
    )  # fmt: skip
    return None if costs is None else float(costs.mean())


def _check_launch(device: torch.device, threads: int) -> None:
    check_threads(threads, BLOCK_THREADS)
    check_device(device, "the CUDA window kernel")


def canvas_costs(packed: PackedMeshes, R: torch.Tensor, t: torch.Tensor, K: torch.Tensor, size: tuple[int, int],
                 offsets: torch.Tensor, other_depth: torch.Tensor | None, other_normals: torch.Tensor | None,
                 dist: torch.Tensor, target_edges: torch.Tensor, edge_threshold: float,
                 threads: int = WINDOW_THREADS) -> np.ndarray | None:  # fmt: skip
    """Forward plus backward cost ``(C,)`` float64 of C canvases (canvas ``c`` in view ``c % V``) by the kernel, as
    :func:`~bop_cender.pose.window_kernel.window_costs` gives them after the CPU's render; None where a vertex lies
    behind the near plane in some canvas.

    Args:
        packed: the meshes drawn in every canvas (their instances' poses ``R (C, I, 3, 3)``, ``t (C, I, 3)`` in the
            canvas's camera frame, mm); K: ``(C, 3, 3)`` the windows' intrinsics (principal point shifted to the
            window); size: the windows' ``(h, w)``; offsets: ``(V, 2)`` each view's window origin in its image.
        other_depth, other_normals: ``(V, h, w)``, ``(V, h, w, 3)`` what else is in the windows (None: nothing).
        dist: ``(V, H, W)`` the target's distance maps; target_edges: ``(V, h, w)`` bool, the edges the backward term
            measures; edge_threshold: raw curvature above which a composite pixel is one of its own edges.
        threads: as :func:`cuda_window_costs`.

    Raises:
        ValueError: ``threads`` out of range, or CPU tensors outside the simulator.
    """
    device = dist.device
    _check_launch(device, threads)
    arguments, z_min = kernel_arguments(packed, R, t, K, size, offsets, other_depth, other_normals, dist, target_edges,
                                        edge_threshold)  # fmt: skip
    out = arguments[-1]
    GUARD.launch(int(R.shape[0]), threads, arguments, device)
    read = torch.cat([out, z_min.double().reshape(1)]).cpu().numpy()  # the call's one wait for the device
    return None if read[-1] < DEFAULT_NEAR else read[:-1]


def kernel_arguments(packed: PackedMeshes, R: torch.Tensor, t: torch.Tensor, K: torch.Tensor, size: tuple[int, int],
                     offsets: torch.Tensor, other_depth: torch.Tensor | None, other_normals: torch.Tensor | None,
                     dist: torch.Tensor, target_edges: torch.Tensor,
                     edge_threshold: float) -> tuple[list, torch.Tensor]:  # fmt: skip
    """The kernel's arguments (:func:`canvas_costs`' inputs on their device, in the kernel's order, scratch
    allocated, the last one ``out (C,)`` float64, which the launch fills) and the least vertex z over the canvases
    (:func:`~bop_cender.render.cuda_loops.exact_key_inputs`; nothing is read back here)."""
    device = dist.device
    C = int(R.shape[0])
    h, w = size
    canvases, z_min = exact_key_inputs(packed, R, t, K, DEFAULT_NEAR)
    if other_depth is None or other_normals is None:
        other = (torch.zeros((0, 1, 1), device=device), torch.zeros((0, 1, 1, 3), device=device))
    else:
        other = (other_depth.float().contiguous(), other_normals.float().contiguous())
    arguments = [*canvases, np.float32(DEFAULT_NEAR), *other, dist.float().contiguous(), offsets.contiguous(),
                 target_edges.to(torch.uint8).contiguous(), np.float32(edge_threshold),
                 torch.empty((C, h * w), dtype=torch.int64, device=device),
                 torch.empty((C, h, w, 3), dtype=torch.float32, device=device),
                 torch.empty(C, dtype=torch.float64, device=device)]  # fmt: skip
    return arguments, z_min
