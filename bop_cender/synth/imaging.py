"""Render the ground truth and the shaded RGB of one synthetic scene in several cameras.

Everything comes from the one batched renderer, so images, depth, masks and curvature targets
are pixel-exact with each other: the RGB is shaded from the very depth / normal / instance buffers
that the masks and ``scene_gt_info`` come from. Shadows are shadow maps rendered by the same
renderer from each light's point of view.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from bop_cender.geometry.poses import transform_points
from bop_cender.render.curvature import curvature
from bop_cender.render.mesh import PackedMeshes, RenderMesh, pack_meshes
from bop_cender.render.rasterizer import render_scene
from bop_cender.render.shading import apply_sensor, make_environment, procedural_texture, random_background, shade_view
from bop_cender.synth.rigs import look_at
from bop_cender.synth.styles import Style

#: Shadow-map resolution and depth bias (mm): the bias avoids self-shadowing "acne".
SHADOW_MAP_SIZE = 384
SHADOW_BIAS_MM = 2.0


@dataclass
class ViewBuffers:
    """Everything one camera sees of a scene.

    Attributes:
        rgb: ``(H, W, 3)`` uint8 (None when shading was not asked for).
        depth: ``(H, W)`` float32 z in mm, 0 = nothing.
        instance: ``(H, W)`` int64 index into the scene's objects, -1 = background.
        curvature: ``(H, W)`` float32 GT curvature map of all objects.
    """

    rgb: np.ndarray | None
    depth: np.ndarray
    instance: np.ndarray
    curvature: np.ndarray


def render_views(
    meshes: Sequence[RenderMesh],
    T_world_model: np.ndarray,
    cameras: Sequence[tuple[np.ndarray, np.ndarray]],
    height: int,
    width: int,
    style: Style | None,
    rng: np.random.Generator,
) -> list[ViewBuffers]:
    """Render M posed objects in V cameras.

    Args:
        meshes: M render meshes (one per object instance; the carrier/table included).
        T_world_model: ``(M, 4, 4)`` object poses (mm).
        cameras: V pairs ``(K (3, 3), T_cam_world (4, 4))``.
        style: appearance; None renders only the ground truth (no RGB).
        rng: draws backgrounds, textures and sensor noise (deterministic per seed).

    Returns:
        One :class:`ViewBuffers` per camera.
    """
    Ks = np.stack([np.asarray(K, dtype=np.float64) for K, _ in cameras])
    T_cw = np.stack([np.asarray(T, dtype=np.float64) for _, T in cameras])
    T_cm = np.einsum("vij,mjk->vmik", T_cw, T_world_model)  # (V, M, 4, 4)
    packed = pack_meshes(list(meshes))  # once, for the views and every light's shadow map
    scene = render_scene(packed, T_cm, Ks, height, width)
    curv = curvature(scene.normals)
    out = []
    shading_inputs = _shading_inputs(style, rng, height, width) if style else None
    maps = shadow_maps(meshes, T_world_model, style, packed) if style is not None else None
    gen = torch.Generator().manual_seed(int(rng.integers(0, 2**62)))
    for v in range(len(cameras)):
        rgb = None
        if style is not None:
            env, texture, background = shading_inputs
            shadow = _shadow_visibility(maps, scene.depth[v], Ks[v], T_cw[v]) if maps is not None else None
            shaded = scene.instance[v]
            if style.hidden:  # in depth and masks, but shaded as background
                shaded = torch.where(torch.isin(shaded, torch.tensor(style.hidden)), -1, shaded)
            linear = shade_view(
                scene.depth[v],
                scene.normals[v],
                shaded,
                torch.as_tensor(Ks[v], dtype=torch.float32),
                torch.as_tensor(T_cw[v], dtype=torch.float32),
                style.materials,
                style.lights,
                env,
                shadow,
                background,
                texture=texture,
                texture_mm_per_px=0.8,
                exposure=style.exposure,
            )
            rgb = apply_sensor(linear, style.sensor, gen).numpy()
        out.append(
            ViewBuffers(
                rgb=rgb,
                depth=scene.depth[v].numpy(),
                instance=scene.instance[v].numpy(),
                curvature=curv[v].numpy(),
            )
        )
    return out


def _shading_inputs(style: Style, rng: np.random.Generator, height: int, width: int):
    """Environment map, carrier texture and background of one scene (shared by all its views)."""
    env = make_environment(rng, style.env_style)
    texture = torch.as_tensor(procedural_texture(rng, 256, style.carrier_texture))
    if style.background == "flat":
        colour = rng.uniform(0.0, 0.35) * rng.uniform(0.8, 1.2, 3)
        background = torch.as_tensor(np.full((height, width, 3), colour, dtype=np.float32))
    else:
        background = torch.as_tensor(random_background(rng, height, width))  # one per scene: a static backdrop
    return env, texture, background


@dataclass(frozen=True)
class ShadowMap:
    """Depth of the scene seen from one light: ``depth (S, S)`` z in mm, camera ``K``, ``T_light_world``."""

    depth: np.ndarray
    K: np.ndarray
    T_light_world: np.ndarray


def shadow_maps(
    meshes: Sequence[RenderMesh], T_world_model: np.ndarray, style: Style, packed: PackedMeshes | None = None
) -> list[ShadowMap]:
    """One shadow map per light, rendered towards the scene centre (shared by every view of the scene).

    ``packed``: the same meshes already packed (:func:`~bop_cender.render.mesh.pack_meshes`), if at hand.
    """
    packed = packed if packed is not None else pack_meshes(list(meshes))
    centre = T_world_model[:, :3, 3].mean(axis=0)
    radius = float(np.linalg.norm(T_world_model[:, :3, 3] - centre, axis=1).max() + max(m.radius for m in meshes))
    maps = []
    for light in style.lights:
        eye = np.asarray(light.position)
        T_light_world = look_at(eye, centre)
        dist = float(np.linalg.norm(eye - centre))
        f = 0.5 * SHADOW_MAP_SIZE * (dist - radius) / (1.15 * radius)
        K_l = np.array([[f, 0, SHADOW_MAP_SIZE / 2], [0, f, SHADOW_MAP_SIZE / 2], [0, 0, 1.0]])
        T_lm = np.einsum("ij,mjk->mik", T_light_world, T_world_model)[None]
        depth = render_scene(packed, T_lm, K_l[None], SHADOW_MAP_SIZE, SHADOW_MAP_SIZE).depth[0].numpy()
        maps.append(ShadowMap(depth, K_l, T_light_world))
    return maps


def _shadow_visibility(
    maps: Sequence[ShadowMap], depth: torch.Tensor, K: np.ndarray, T_cam_world: np.ndarray
) -> torch.Tensor:
    """``(L, H, W)`` 1 where the surface point seen by the camera is lit by light l, else 0.

    A surface point is lit if it is no further from the light than its shadow map says (plus a
    bias against self-shadowing), or if it falls outside the map.
    """
    H, W = depth.shape
    v, u = torch.meshgrid(torch.arange(H, dtype=torch.float32), torch.arange(W, dtype=torch.float32), indexing="ij")
    x = (u + 0.5 - float(K[0, 2])) / float(K[0, 0]) * depth
    y = (v + 0.5 - float(K[1, 2])) / float(K[1, 1]) * depth
    p_cam = np.stack([x.numpy(), y.numpy(), depth.numpy()], -1).reshape(-1, 3)
    p_world = transform_points(np.linalg.inv(T_cam_world), p_cam)
    vis = []
    for m in maps:
        p_l = transform_points(m.T_light_world, p_world)
        z = p_l[:, 2]
        f, c = m.K[0, 0], m.K[0, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uu = np.floor(f * p_l[:, 0] / z + c).astype(np.int64)
            vv = np.floor(f * p_l[:, 1] / z + c).astype(np.int64)
        S = m.depth.shape[0]
        inside = (z > 0) & (uu >= 0) & (uu < S) & (vv >= 0) & (vv < S)
        occluder = np.zeros_like(z)
        occluder[inside] = m.depth[vv[inside], uu[inside]]
        lit = ~inside | (occluder == 0) | (z <= occluder + SHADOW_BIAS_MM + 0.004 * z)
        vis.append(lit.reshape(H, W))
    return torch.as_tensor(np.stack(vis), dtype=torch.float32)
