"""The stage-1 -> stage-2/3 contract: per-view center and curvature heatmaps of one scene."""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch


def scene_channel_ids(channel_obj_ids: tuple[int, ...], present_ids: set[int] | frozenset[int]) -> tuple[int, ...]:
    """The center channels a scene's maps hold: those of ``channel_obj_ids`` whose object its GT holds
    (``present_ids``), in their order; the others would be 0 in every view (a T-LESS group of 5 views at 720x540:
    5 of 30 channels, 39 MB instead of 233 MB). All of them where the GT holds none (nothing is known)."""
    return tuple(i for i in channel_obj_ids if i in present_ids) or channel_obj_ids


@dataclass(frozen=True, eq=False)
class Heatmaps:
    """Center and curvature heatmaps of a scene's V views, on the device that made them.

    Attributes:
        center: ``(V, C, H, W)`` float32 in [0, 1]: probability of an object centre per pixel; one
            shared channel (DIMO, ``channel_obj_ids`` None) or one channel per object id (T-LESS).
        curvature: ``(V, H, W)`` float32 in [0, 1]: ``clip(curvature / c, 0, 1)`` of the visible target
            surfaces (see :mod:`bop_cender.net.targets`).
        channel_obj_ids: object id of each center channel, or None for one channel shared by all objects. A
            scene's maps may hold some of a network's ids only: those its GT holds (:func:`scene_channel_ids`).
        im_ids: the image id of each view, in order.
        curvature_threshold: where stage 3 should binarise this curvature, when its maker knows better than
            ``PoseConfig.t_b`` (a network: its calibrated threshold, ``poses.network.t_b``); None: ``t_b``
            (the oracle's rendered curvature).
        centers_from_network: the centre maps are a network's (True) or rendered from the ground truth (False):
            stage 3 searches wider around a network's centres (``poses.network``).
        exclusive_channels: the center channels split one class-agnostic probability among the object ids (a
            factored network's: their sum is it) rather than each being a probability of its own (the oracle's,
            independent channels): how stage 2 joins them (:func:`bop_cender.centers.class_agnostic_map`).
    """

    center: torch.Tensor
    curvature: torch.Tensor
    channel_obj_ids: tuple[int, ...] | None
    im_ids: tuple[int, ...]
    curvature_threshold: float | None = None
    centers_from_network: bool = False
    exclusive_channels: bool = False

    def __post_init__(self) -> None:
        if self.center.dim() != 4 or self.curvature.dim() != 3:
            raise ValueError(
                f"expected center (V, C, H, W) and curvature (V, H, W), got {tuple(self.center.shape)} and"
                f" {tuple(self.curvature.shape)}"
            )
        V, C, H, W = self.center.shape
        if tuple(self.curvature.shape) != (V, H, W):
            raise ValueError(
                f"curvature {tuple(self.curvature.shape)} does not match center {tuple(self.center.shape)}"
            )
        t = self.curvature_threshold
        if t is not None and not 0.0 <= t < 1.0:  # NaN too: it would leave no edge at all
            raise ValueError(f"curvature_threshold must be in [0, 1), got {t}")
        if len(self.im_ids) != V:
            raise ValueError(f"{len(self.im_ids)} image ids for {V} views")
        if self.channel_obj_ids is not None and len(self.channel_obj_ids) != C:
            raise ValueError(f"{len(self.channel_obj_ids)} channel object ids for {C} center channels")
        if self.channel_obj_ids is None and C != 1:
            raise ValueError(f"a shared center channel was declared but there are {C} channels")

    @property
    def num_views(self) -> int:
        return int(self.center.shape[0])

    @property
    def size(self) -> tuple[int, int]:
        """``(H, W)``."""
        return int(self.center.shape[2]), int(self.center.shape[3])

    def channel_of(self, obj_id: int) -> int:
        """The center channel that holds ``obj_id`` (0 when the channel is shared)."""
        if self.channel_obj_ids is None:
            return 0
        return self.channel_obj_ids.index(obj_id)

    def to(self, device: torch.device | str) -> Heatmaps:
        return replace(self, center=self.center.to(device), curvature=self.curvature.to(device))
