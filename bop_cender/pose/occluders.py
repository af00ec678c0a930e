"""The objects already placed, rendered as the depth that hides the next object's pixels behind them.

The paper places objects one by one, most visible first, each fitted under the depth of those placed before it
(:func:`occluder_depth`); a later sweep searches an object again only where the others now hide other pixels of it
than when it was fitted (:func:`hidden_pixels_differ`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import torch

from bop_cender.pose.types import PlacedObject, SceneCameras
from bop_cender.render.backend import RenderBackend
from bop_cender.render.candidate_curvature import occluded
from bop_cender.render.mesh import RenderMesh
from bop_cender.render.rasterizer import render_scene


def occluder_depth(
    placed: Sequence[PlacedObject],
    cameras: SceneCameras,
    meshes: Callable[[int], RenderMesh],
    backend: RenderBackend,
) -> torch.Tensor:
    """``(V, H, W)`` depth (mm) of the placed objects rendered together in every view by ``backend`` (0: nothing), on
    the device of their meshes."""
    T_wm = np.stack([p.T_world_model for p in placed])
    T_cm = np.einsum("vij,mjk->vmik", cameras.T_cam_world, T_wm)
    placed_meshes = [meshes(p.obj_id) for p in placed]
    device = placed_meshes[0].device
    render = render_scene(
        placed_meshes,
        torch.as_tensor(T_cm, dtype=torch.float32, device=device),
        torch.as_tensor(cameras.Ks, dtype=torch.float32, device=device),
        cameras.height,
        cameras.width,
        backend=backend,
    )
    return render.depth


def hidden_pixels_differ(
    obj: PlacedObject,
    before: torch.Tensor | None,
    after: torch.Tensor | None,
    cameras: SceneCameras,
    meshes: Callable[[int], RenderMesh],
    backend: RenderBackend,
) -> bool:
    """Whether the occluder depth ``after (V, H, W)`` hides other pixels of ``obj`` than ``before`` did
    (the render cost's rule; None: no occluder). Where it hides the same ones, the object's cost and its
    search see the same image, and a later sweep keeps its pose."""
    if before is None and after is None:
        return False
    T_cm = np.einsum("vij,jk->vik", cameras.T_cam_world, obj.T_world_model)[:, None]
    mesh = meshes(obj.obj_id)
    depth = render_scene(
        [mesh],
        torch.as_tensor(T_cm, dtype=torch.float32, device=mesh.device),
        torch.as_tensor(cameras.Ks, dtype=torch.float32, device=mesh.device),
        cameras.height,
        cameras.width,
        backend=backend,
    ).depth

    def hidden(occ: torch.Tensor | None) -> torch.Tensor:
        return torch.zeros_like(depth, dtype=torch.bool) if occ is None else occluded(depth, occ)

    return not torch.equal(hidden(before), hidden(after))
