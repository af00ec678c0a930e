"""Stage 3's last step (ours): each placed object refined on the scene cost around it, the others fixed.

Why. After the sweeps every object sits where the edge proxy (:mod:`bop_cender.pose.edge_cost`) is
smallest, and the sweeps only choose *between* refined poses by the scene cost
(:meth:`~bop_cender.pose.backend.Backend.scene_cost`: the whole placement rendered together, forward plus backward
edge distance). Where the proxy's minimum and the scene's differ by a little, nothing moves the object
to the scene's. Measured on oracle heatmaps (DIMO-layout seed 4242, scene 000019_00, five 53 mm discs):
a fully visible disc placed 6 degrees from its symmetric pose (MSSD 5.5 % of its diameter: a miss at
BOP's strictest threshold); put at its true pose, the scene cost falls 1.079 -> 0.940; Nelder-Mead on the
scene cost from the placed pose brings it to 0.6 degrees, and the other four discs' centres from 0.4-0.8
mm to under 0.2 mm. The render cost's polish (removed, once ``polish_maxfev``) did not do this: it is the
paper's one-sided cost of one object, blind to the target edges a tilted pose leaves unexplained.

How, cheaply. The scene cost renders every object in every full frame (23 ms per pose for 4 parts in 7
views on one CPU thread, against 4.5 ms for the windowed cost: ``python scripts/bench_run.py``, section "Scene
polish"). Only one object moves, so the cost is taken in a window around it in each view
(its bounding sphere's projection plus a margin): the other objects are rendered once into the windows,
each trial pose of the moving one is rendered into them alone and composited by depth, and the forward and
backward terms are those of :meth:`~bop_cender.pose.backend.Backend.scene_cost` inside the windows (normalised
over the window's pixels, and a window without any composite edge costs the image diagonal as a frame
does: a constant offset against the full cost, the same ranking). A pose the window polish finds is kept
only where the full scene cost falls. The backend computes it (:meth:`~bop_cender.pose.backend.Backend.window_costs`;
here: the ``auto`` and ``numba`` backends'; ``torch``: torch operators throughout). On the CPU the steps after the
render (composite, curvature, both terms) run as one compiled pass (:mod:`bop_cender.pose.window_kernel`; ``python scripts/bench_run.py``, section "Scene
polish", times a call both ways), and the render itself is the compiled loop of
:mod:`bop_cender.render.compiled_raster` (the torch pipeline's bits without its fixed cost of about 2,000
operators a call: ``scripts/bench_run.py``, section "Scene polish", times both renders). On CUDA the whole call, render
included, is one kernel (:mod:`bop_cender.pose.cuda_window_kernel`: the torch steps cost 15 ms a call on an H200,
launch bound), where numba's CUDA target works; else the torch steps.

Target edges within ``WINDOW_BORDER_PX`` of a window side that lies inside the image are left out of the
backward term: they are mostly a neighbour's edges spilling across the side, which the windowed composite
cannot explain (it renders nothing beyond the window), and they would pull the moving part toward them
(under 0.03 degree and 0.03 mm on the test scene where it was found).
Measured with oracle heatmaps (DIMO-layout seed 4242): AR_MSPD<5px 0.960 -> 0.965, AR_MSSD<5% 0.964 -> 0.958
(float-level changes alone move these figures as much: the edge cost with another summation order gave 0.971
and 0.964); kept because it removes a bias.

Not bounded: the polish may move a part as far as the search's bounds, so a trial pose can leave the window
it is costed in (then only what stays inside is costed). Bounding the moves to a quarter of the margin (in
mm, translation and rotation at the part's radius) lost: AR_MSSD<5% 0.958 -> 0.938 on the same set. The
polish's larger moves are useful, and the full scene cost decides whether a polished pose is kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from bop_cender.pose.cost import view_costs
from bop_cender.pose.coverage import mean_distance_to_own_edges
from bop_cender.render.backend import RenderBackend
from bop_cender.render.curvature import curvature
from bop_cender.render.mesh import PackedMeshes, RenderMesh, pack_meshes
from bop_cender.render.rasterizer import render_scene

WINDOW_BORDER_PX = 2  # target edges this close to a window side inside the image are not the moving part's


@dataclass(frozen=True)
class SceneWindow:
    """The scene around one object in every view: windows ``(h, w)`` at ``offsets (V, 2)`` (row, column), the
    other objects' depth ``(V, h, w)`` (0: nothing) and normals ``(V, h, w, 3)`` there, the target's edges
    ``(V, h, w)`` (bool) there (less those within :data:`WINDOW_BORDER_PX` of a side inside the image), the full
    distance maps ``(V, H, W)`` and the windows' intrinsics ``(V, 3, 3)``."""

    mesh: RenderMesh
    T_cam_world: np.ndarray
    K: torch.Tensor
    offsets: torch.Tensor
    size: tuple[int, int]
    other_depth: torch.Tensor
    other_normals: torch.Tensor
    target_edges: torch.Tensor
    dist: torch.Tensor
    edge_threshold: float
    packed: PackedMeshes | None = None


def torch_window_costs(window: SceneWindow, depth: torch.Tensor, normals: torch.Tensor, m: int) -> np.ndarray:
    """``(m,)`` windowed scene costs (pixels: the mean over the views of forward plus backward, as
    :meth:`~bop_cender.pose.backend.Backend.scene_cost` inside the windows) of m trial poses of the window's part, from
    its render into the windows, ``depth (m V, h, w)`` and ``normals (m V, h, w, 3)`` (canvas ``c`` = trial ``c // V``
    in view ``c % V``), by torch operators: the part composited over the other parts by depth, the curvature of the
    composite, the forward and the backward terms. What :meth:`~bop_cender.pose.backend.Backend.window_costs` is in the
    ``torch`` backend."""
    V = len(window.T_cam_world)
    other_depth = window.other_depth.repeat(m, 1, 1)
    front = (depth > 0) & ((other_depth == 0) | (depth < other_depth))
    composite = torch.where(front[..., None], normals, window.other_normals.repeat(m, 1, 1, 1))
    curv = curvature(composite)  # (m V, h, w)
    forward = view_costs(curv, window.dist, window.offsets.repeat(m, 1))
    backward = mean_distance_to_own_edges(curv, window.target_edges.repeat(m, 1, 1), window.edge_threshold)
    return (forward + backward).view(m, V).mean(1).double().cpu().numpy()


def window_poses(window: SceneWindow, T_world_model: np.ndarray) -> torch.Tensor:
    """``T_cam_model (m V, 1, 4, 4)`` float32 on the window's device of trial poses ``T_world_model (m, 4, 4)`` of its
    part: canvas ``c`` = trial ``c // V`` in view ``c % V``, as the render of the part into the windows takes them."""
    m, V = len(T_world_model), len(window.T_cam_world)
    T_cm = np.einsum("vij,mjk->mvik", window.T_cam_world, T_world_model).reshape(m * V, 1, 4, 4)
    return torch.as_tensor(T_cm, dtype=torch.float32, device=window.dist.device)


def scene_window(
    mesh: RenderMesh,
    T_world_model: np.ndarray,
    others: list[tuple[RenderMesh, np.ndarray]],
    Ks: np.ndarray,
    T_cam_world: np.ndarray,
    target_edges: torch.Tensor,
    dist: torch.Tensor,
    edge_threshold: float,
    margin_px: int,
    backend: RenderBackend | None = None,
) -> SceneWindow:
    """The :class:`SceneWindow` of an object at ``T_world_model (4, 4)`` among ``others`` (mesh, pose) pairs.

    The window of a view is the projection of the object's bounding sphere (``mesh.radius`` about the model
    origin) plus ``margin_px``, one size for all views (the largest, at most the image), placed around the
    projected centre and kept inside the image. ``Ks (V, 3, 3)``, ``T_cam_world (V, 4, 4)``, the target's
    ``target_edges (V, H, W)`` and their distance maps ``dist (V, H, W)``; ``backend`` renders the others
    (:mod:`bop_cender.render.backend`; None: ``auto``)."""
    V, H, W = target_edges.shape
    device = dist.device
    origin = T_cam_world[:, :3, :3] @ T_world_model[:3, 3] + T_cam_world[:, :3, 3]  # (V, 3) model origin in cameras
    z = np.maximum(origin[:, 2], 1e-3)
    u = Ks[:, 0, 0] * origin[:, 0] / z + Ks[:, 0, 2]
    v = Ks[:, 1, 1] * origin[:, 1] / z + Ks[:, 1, 2]
    half = np.ceil(mesh.radius * np.maximum(Ks[:, 0, 0], Ks[:, 1, 1]) / z) + margin_px  # (V,) pixels
    h = int(min(H, 2 * half.max()))
    w = int(min(W, 2 * half.max()))
    top = np.clip(np.round(v - h / 2), 0, H - h).astype(np.int64)
    left = np.clip(np.round(u - w / 2), 0, W - w).astype(np.int64)
    top_t, left_t = torch.as_tensor(top, device=device), torch.as_tensor(left, device=device)
    K = torch.as_tensor(Ks, dtype=torch.float32, device=device).clone()
    K[:, 0, 2] -= left_t.float()
    K[:, 1, 2] -= top_t.float()
    rows = top_t[:, None] + torch.arange(h, device=device)  # (V, h)
    cols = left_t[:, None] + torch.arange(w, device=device)  # (V, w)
    views = torch.arange(V, device=device)[:, None, None]
    edges = target_edges.to(device)[views, rows[:, :, None], cols[:, None, :]]  # (V, h, w)
    edges &= _inside_border(top_t, left_t, (h, w), (H, W), WINDOW_BORDER_PX)
    if others:
        T_cm = np.einsum("vij,mjk->vmik", T_cam_world, np.stack([T for _, T in others]))
        T = torch.as_tensor(T_cm, dtype=torch.float32, device=device)
        render = render_scene([mesh for mesh, _ in others], T, K, h, w, backend=backend)
        other_depth, other_normals = render.depth, render.normals
    else:
        other_depth = torch.zeros((V, h, w), device=device)
        other_normals = torch.zeros((V, h, w, 3), device=device)
    offsets = torch.stack([top_t, left_t], dim=1)
    packed = pack_meshes([mesh.to(device)]) if device.type == "cuda" else None  # the CUDA kernel's faces, once
    return SceneWindow(
        mesh, T_cam_world, K, offsets, (h, w), other_depth, other_normals, edges, dist, float(edge_threshold), packed
    )


def _inside_border(
    top: torch.Tensor, left: torch.Tensor, size: tuple[int, int], image: tuple[int, int], border: int
) -> torch.Tensor:
    """``(V, h, w)`` bool: False within ``border`` pixels of each window side that lies inside the image (a window
    at ``top``, ``left`` ``(V,)`` of ``size`` in an ``image`` (H, W)); sides on the image's border keep theirs."""
    (h, w), (H, W) = size, image
    r = torch.arange(h, device=top.device)[None]
    c = torch.arange(w, device=top.device)[None]
    rows = ((top > 0)[:, None] & (r < border)) | ((top + h < H)[:, None] & (r >= h - border))  # (V, h)
    cols = ((left > 0)[:, None] & (c < border)) | ((left + w < W)[:, None] & (c >= w - border))  # (V, w)
    return ~(rows[:, :, None] | cols[:, None, :])
