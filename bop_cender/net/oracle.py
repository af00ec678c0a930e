"""The oracle predictor: GT heatmaps served where the network's would be (``--heatmaps oracle``).

Stages 2 and 3 are built, tested and measured on it without any network; the optional degradations
(blur, noise, missed objects) tell how good the network has to be.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace

import numpy as np
import torch
import torch.nn.functional as F

from bop_cender.data.types import ObjectModel, Scene
from bop_cender.net.heatmaps import Heatmaps, scene_channel_ids
from bop_cender.net.targets import TargetConfig, center_channel_ids, scene_targets
from bop_cender.render.mesh import RenderMesh


@dataclass(frozen=True)
class Degradation:
    """Ways to make oracle heatmaps worse, for ablations (all off by default).

    Attributes:
        blur_sigma: Gaussian blur of both heatmaps (pixels).
        noise_std: additive Gaussian noise (then clipped to [0, 1]).
        miss_prob: probability that an object is missing from the center heatmaps of all views.
        seed: seed of the noise and the misses (per scene it is combined with the scene key).
    """

    blur_sigma: float = 0.0
    noise_std: float = 0.0
    miss_prob: float = 0.0
    seed: int = 0


class OraclePredictor:
    """Heatmaps rendered from the ground truth (:func:`bop_cender.net.targets.scene_targets`).

    With one center channel per object id (``channel_obj_ids``, default every target id), a scene's heatmaps hold
    the channels of the ids in its GT only (:func:`~bop_cender.net.heatmaps.scene_channel_ids`), as
    :class:`~bop_cender.net.predictor.NetPredictor`'s do. A :class:`Degradation`'s noise is drawn for those channels
    only (since 2026-12-07: its draws, and so noisy figures with per-object channels, differ from before)."""

    name = "oracle"

    def __init__(
        self,
        models: Mapping[int, ObjectModel],
        meshes: Callable[[int], RenderMesh],
        config: TargetConfig,
        channel_obj_ids: tuple[int, ...] | None = None,
        degradation: Degradation | None = None,
        device: torch.device | str = "cpu",
    ) -> None:
        self.models, self.meshes, self.config = models, meshes, config
        self.channel_obj_ids = channel_obj_ids
        self.degradation = degradation or Degradation()
        self.device = torch.device(device)

    def predict(self, scene: Scene) -> Heatmaps:
        d = self.degradation
        channels = center_channel_ids(self.models, self.config, self.channel_obj_ids)
        if channels is not None:
            channels = scene_channel_ids(channels, {g.obj_id for g in scene.gt})
        if d.miss_prob > 0:
            rng = np.random.default_rng([d.seed, _key_seed(scene.key)])
            kept = tuple(g for g in scene.gt if rng.random() >= d.miss_prob or not self.models[g.obj_id].is_target)
            center_scene = replace(scene, gt=kept)
            full = scene_targets(scene, self.models, self.meshes, self.config, channels, self.device)
            missed = scene_targets(center_scene, self.models, self.meshes, self.config, channels, self.device)
            maps = Heatmaps(missed.center, full.curvature, full.channel_obj_ids, full.im_ids)
        else:
            maps = scene_targets(scene, self.models, self.meshes, self.config, channels, self.device)
        return degrade(maps, d, _key_seed(scene.key)) if d.blur_sigma > 0 or d.noise_std > 0 else maps


def degrade(maps: Heatmaps, d: Degradation, scene_seed: int = 0) -> Heatmaps:
    """Blur and add noise to both heatmaps (deterministic per ``d.seed`` and ``scene_seed``)."""
    center, curv = maps.center, maps.curvature
    if d.blur_sigma > 0:
        center = _blur(center, d.blur_sigma)
        curv = _blur(curv[:, None], d.blur_sigma)[:, 0]
    if d.noise_std > 0:
        gen = torch.Generator(device="cpu").manual_seed(
            int(np.random.default_rng([d.seed, scene_seed]).integers(2**62))
        )
        center = center + d.noise_std * torch.randn(center.shape, generator=gen).to(center.device)
        curv = curv + d.noise_std * torch.randn(curv.shape, generator=gen).to(curv.device)
    return Heatmaps(center.clamp(0, 1), curv.clamp(0, 1), maps.channel_obj_ids, maps.im_ids)


def _blur(x: torch.Tensor, sigma: float) -> torch.Tensor:
    """Separable Gaussian blur of ``(N, C, H, W)``."""
    radius = max(1, int(3 * sigma + 0.5))
    k = torch.exp(-(torch.arange(-radius, radius + 1, dtype=x.dtype, device=x.device) ** 2) / (2 * sigma**2))
    k = k / k.sum()
    N, C, H, W = x.shape
    y = x.reshape(N * C, 1, H, W)
    y = F.conv2d(F.pad(y, (radius, radius, 0, 0), mode="replicate"), k.view(1, 1, 1, -1))
    y = F.conv2d(F.pad(y, (0, 0, radius, radius), mode="replicate"), k.view(1, 1, -1, 1))
    return y.view(N, C, H, W)


def _key_seed(key: str) -> int:
    """A stable integer from a scene key (Python's hash() is salted per process)."""
    return zlib.crc32(key.encode("utf8"))
