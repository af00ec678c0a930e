"""Ground-truth heatmaps of a scene (paper, Section 2.1 and appendix), from the one batched renderer.

- **Curvature**: the renderer's view-space curvature (:mod:`bop_cender.render.curvature`) of the
  *visible surfaces of the target objects*: the whole pile is rendered (carriers and distractors
  included, so that they occlude), then every pixel that does not show a target object is set to
  background before the Prewitt gradients, so target silhouettes (also where a carrier or an
  occluder cuts them) are edges and nothing of a carrier is. Mapped to [0, 1] as
  ``clip(curvature / curvature_scale, 0, 1)`` (docs/design.md, "The renderer").
- **Centers**: a Gaussian blob per object at the projection of its 3D centre (bounding-box centre of
  ``models_info.json``), ``sigma = s_e * mean bbox extent * 100 / distance(centre, camera)`` (pixels,
  extents and distance in mm), peak 1, overlapping blobs combined by max, evaluated at pixel centres
  ``(u + 0.5, v + 0.5)``. Only objects whose visible fraction in that view exceeds ``min_visib_fract``
  get a blob (T-LESS: 0.5, the paper's appendix).

On synthetic data the render is exact; on a real download it relies on the GT poses and models as the
paper does (its T-LESS targets apply the provided visibility masks: a render of all annotated objects
gives the same visible masks up to annotation error).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
import torch

from bop_cender.data.industrial_params import INDUSTRIAL
from bop_cender.data.types import ObjectModel, Scene
from bop_cender.errors import DatasetError
from bop_cender.net.heatmaps import Heatmaps
from bop_cender.net.votes import VoteTargets, vote_targets
from bop_cender.render.curvature import DEFAULT_CURVATURE_SCALE, curvature
from bop_cender.render.mesh import RenderMesh
from bop_cender.render.rasterizer import render_objects_separately, render_scene
from bop_cender.settings_checks import POSITIVE, Bound, check_settings


@dataclass(frozen=True)
class TargetConfig:
    """How GT heatmaps are made.

    Attributes:
        s_e: blob size factor (paper appendix: 0.5 DIMO, 1.25 T-LESS).
        curvature_scale: ``c`` in ``clip(curvature / c, 0, 1)`` (ours: 4). A unit normal stepping to
            background gives a curvature of 3 to 4.2, a 90-degree crease about 3, a flat face 0; but a
            curved surface only a few pixels across (a 13 mm shaft in DIMO's 320x256 views) reaches
            1.3 to 2.9 all over. With c = 1 such parts were one saturated blob, inside which every pose
            cost nothing (3 of 4 shafts of a pile missed by 5-45 % of their diameter); c = 4 keeps the
            contrast between silhouettes and curved surfaces (the same pile: all 4 within 1.1 %).
        min_visib_fract: objects less visible than this in a view get no center blob there (paper
            T-LESS: 0.5; DIMO gives no number: 0.1 drops only objects that are all but hidden).
        per_object_channels: one center channel per object id (T-LESS) instead of one shared (DIMO).
    """

    s_e: float = 0.5
    curvature_scale: float = DEFAULT_CURVATURE_SCALE
    min_visib_fract: float = 0.1
    per_object_channels: bool = False

    def __post_init__(self) -> None:
        check_settings(
            "targets",
            self,
            {"s_e": POSITIVE, "curvature_scale": POSITIVE, "min_visib_fract": Bound(0.0, 1.0, high_open=True)},
            flags=("per_object_channels",),
        )

    @staticmethod
    def for_dataset(name: str) -> TargetConfig:
        """The paper's settings: DIMO one shared channel, s_e 0.5; T-LESS / BOP one channel per object, s_e 1.25.

        Ours for bin-picking piles (``industrial``: the BOP-Industrial datasets and a multi-sensor ``bop`` folder): one
        channel per object, DIMO's blobs and visibility rule (s_e 0.5, a blob from 10 % visible). Measured with oracle
        heatmaps on a synthetic industrial set (seed 4401, `--task detection`): bop25_mAP 0.395 with T-LESS's targets
        (a part under half visible in a view gets no blob there: in a bin most are), 0.748 with min_visib_fract 0.1,
        0.893 with s_e 0.5 too (``results/accuracy/industrial/README.md``)."""
        if name == "dimo":
            return TargetConfig(s_e=0.5, min_visib_fract=0.1, per_object_channels=False)
        if name in INDUSTRIAL_TARGETS:
            return TargetConfig(s_e=0.5, min_visib_fract=0.1, per_object_channels=True)
        return TargetConfig(s_e=1.25, min_visib_fract=0.5, per_object_channels=True)


#: The dataset names whose targets are the bin-picking ones (:meth:`TargetConfig.for_dataset`).
INDUSTRIAL_TARGETS = frozenset({"industrial", *INDUSTRIAL})


def blob_sigma(s_e: float, bbox_size: np.ndarray, distance_mm: np.ndarray) -> np.ndarray:
    """``sigma = s_e * mean(bbox_size) * 100 / distance`` in pixels (paper appendix), any shape of distances."""
    return s_e * float(np.mean(bbox_size)) * 100.0 / np.asarray(distance_mm, dtype=np.float64)


def center_channel_ids(
    models: Mapping[int, ObjectModel], config: TargetConfig, channel_obj_ids: tuple[int, ...] | None = None
) -> tuple[int, ...] | None:
    """The object id of each center channel of the targets: None for one shared channel, else ``channel_obj_ids``
    or, where not given, every target object's id in ascending order."""
    if not config.per_object_channels:
        return None
    return channel_obj_ids or tuple(sorted(i for i, m in models.items() if m.is_target))


def scene_targets(
    scene: Scene,
    models: Mapping[int, ObjectModel],
    meshes: Callable[[int], RenderMesh],
    config: TargetConfig,
    channel_obj_ids: tuple[int, ...] | None = None,
    device: torch.device | str = "cpu",
) -> Heatmaps:
    """GT center and curvature heatmaps of every view of ``scene`` (:func:`scene_targets_with_votes` without the
    votes)."""
    return scene_targets_with_votes(scene, models, meshes, config, channel_obj_ids, device)[0]


def scene_targets_with_votes(
    scene: Scene,
    models: Mapping[int, ObjectModel],
    meshes: Callable[[int], RenderMesh],
    config: TargetConfig,
    channel_obj_ids: tuple[int, ...] | None = None,
    device: torch.device | str = "cpu",
) -> tuple[Heatmaps, VoteTargets]:
    """GT center and curvature heatmaps of every view of ``scene``, and its centre votes' targets
    (:mod:`bop_cender.net.votes`: the visible pixels of every object that has a center blob in a view point at
    its blob's centre).

    Args:
        scene: views and GT objects (world frame).
        models: the dataset's models (targets and occluders), by id.
        meshes: the renderer's mesh of an object id (cached by the caller).
        config: see :class:`TargetConfig`.
        channel_obj_ids: object id per center channel when ``config.per_object_channels`` (default: the
            target ids of ``models``, sorted).
        device: where to render.

    Returns:
        :class:`Heatmaps` with center ``(V, C, H, W)`` and curvature ``(V, H, W)``, and :class:`VoteTargets`.

    Raises:
        DatasetError: views of different sizes (naming the first odd one's image).
    """
    views = scene.views
    H, W = views[0].height, views[0].width
    if any((v.height, v.width) != (H, W) for v in views):
        odd = next(v for v in views if (v.height, v.width) != (H, W))
        raise DatasetError(
            f"scene {scene.key}: views of different sizes are not supported: this one is {odd.width}x{odd.height},"
            f" the scene's first {W}x{H}",
            file=odd.rgb_path or odd.source,
            field="size",
        )
    channels = center_channel_ids(models, config, channel_obj_ids)
    V = len(views)
    n_channels = 1 if channels is None else len(channels)
    center = torch.zeros((V, n_channels, H, W), dtype=torch.float32, device=device)
    curv = torch.zeros((V, H, W), dtype=torch.float32, device=device)
    gt = [g for g in scene.gt if g.obj_id in models]
    votes = VoteTargets(np.zeros((V, H, W), np.uint8), tuple(np.zeros((0, 3), np.float32) for _ in range(V)))
    if gt:
        visible, visib_fract = _visibility(scene, gt, meshes, device)
        target = torch.tensor([models[g.obj_id].is_target for g in gt], device=device)
        shows_target = (visible.instance >= 0) & target[visible.instance.clamp_min(0)]
        normals = visible.normals * shows_target[..., None]
        curv = (curvature(normals) / config.curvature_scale).clamp_(0.0, 1.0)
        blobs = _blobs(scene, gt, models, config, channels, visib_fract)
        center = _center_maps(blobs, V, n_channels, (H, W), device)
        votes = vote_targets(visible.instance, blobs.xy, blobs.has_blob)
    heatmaps = Heatmaps(center=center, curvature=curv, channel_obj_ids=channels, im_ids=tuple(scene.im_ids))
    return heatmaps, votes


def _visibility(scene: Scene, gt, meshes, device):
    """The pile rendered together (occlusion) and each object's visible fraction per view ``(V, M)``."""
    Ks = np.stack([v.K for v in scene.views])
    T_cw = np.stack([v.T_cam_world for v in scene.views])
    T_wm = np.stack([g.T_world_model for g in gt])
    T_cm = torch.as_tensor(np.einsum("vij,mjk->vmik", T_cw, T_wm), dtype=torch.float32, device=device)
    H, W = scene.views[0].height, scene.views[0].width
    mesh_list = [meshes(g.obj_id).to(device) for g in gt]
    together = render_scene(mesh_list, T_cm, torch.as_tensor(Ks, device=device), H, W)
    alone = render_objects_separately(mesh_list, T_cm, torch.as_tensor(Ks, device=device), H, W)
    full = alone.mask.flatten(2).sum(-1)  # (V, M)
    idx = together.instance.flatten(1)  # (V, HW)
    vis = torch.zeros_like(full)
    vis.scatter_add_(1, idx.clamp_min(0), (idx >= 0).to(vis.dtype))
    fract = torch.where(full > 0, vis.to(torch.float64) / full.clamp_min(1).to(torch.float64), 0.0)
    return together, fract.cpu().numpy()


@dataclass(frozen=True)
class _Blobs:
    """The center blobs of a scene's GT objects ``(V, M)``: whether each has one in each view, its centre ``xy
    (V, M, 2)`` (continuous image coordinates), ``sigma`` (pixels) and channel."""

    has_blob: np.ndarray
    xy: np.ndarray
    sigma: np.ndarray
    channel: np.ndarray


def _blobs(scene, gt, models, config, channels, visib_fract) -> _Blobs:
    V, M = len(scene.views), len(gt)
    has_blob = np.zeros((V, M), bool)
    xy = np.zeros((V, M, 2))
    sigma = np.ones((V, M))
    channel = np.zeros(M, np.int64)
    for m, g in enumerate(gt):
        model = models[g.obj_id]
        if not model.is_target or (channels is not None and g.obj_id not in channels):
            continue
        channel[m] = 0 if channels is None else channels.index(g.obj_id)
        center_world = g.T_world_model[:3, :3] @ model.center + g.T_world_model[:3, 3]
        for i, view in enumerate(scene.views):
            if visib_fract[i, m] <= config.min_visib_fract:
                continue
            p = view.T_cam_world[:3, :3] @ center_world + view.T_cam_world[:3, 3]
            if p[2] <= 0:
                continue
            xy[i, m] = (view.K @ p)[:2] / p[2]
            sigma[i, m] = float(blob_sigma(config.s_e, model.bbox_size, np.linalg.norm(p)))
            has_blob[i, m] = True
    return _Blobs(has_blob, xy, sigma, channel)


def _center_maps(blobs: _Blobs, V: int, n_channels: int, size, device) -> torch.Tensor:
    """``(V, C, H, W)`` max-combined Gaussian blobs at the projected 3D centres."""
    H, W = size
    out = torch.zeros((V, n_channels, H, W), dtype=torch.float32, device=device)
    u = torch.arange(W, dtype=torch.float32, device=device) + 0.5
    v = torch.arange(H, dtype=torch.float32, device=device) + 0.5
    for i, m in zip(*np.nonzero(blobs.has_blob), strict=True):
        x, y = blobs.xy[i, m]
        sigma = blobs.sigma[i, m]
        c = int(blobs.channel[m])
        gx = torch.exp(-((u - float(x)) ** 2) / (2 * sigma**2))
        gy = torch.exp(-((v - float(y)) ** 2) / (2 * sigma**2))
        torch.maximum(out[i, c], gy[:, None] * gx[None, :], out=out[i, c])
    return out
