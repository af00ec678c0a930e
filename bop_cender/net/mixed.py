"""Heatmaps of two sources in one: centres from one predictor, curvature from another.

The issue's stage-1 ablations ask where a network run loses: with the centres of the oracle and the
network's curvature (``--heatmaps oracle-centers``) stage 2 is perfect and stage 3 sees what the network
predicts; with the network's centres and the oracle's curvature (``--heatmaps oracle-curvature``) the
reverse. The difference of each to the oracle run and to the network run splits the network's loss
between its two heads.
"""

from __future__ import annotations

from typing import Protocol

from bop_cender.data.types import Scene
from bop_cender.net.heatmaps import Heatmaps


class _Predictor(Protocol):
    name: str

    def predict(self, scene: Scene) -> Heatmaps: ...


class MixedPredictor:
    """The center heatmaps of ``centers_from`` with the curvature heatmaps of ``curvature_from``.

    Both must see the scene at one image size and in one view order; the centre channels (and their
    object ids) are those of ``centers_from``. The result is on ``centers_from``'s device.
    """

    def __init__(self, centers_from: _Predictor, curvature_from: _Predictor) -> None:
        self.centers_from, self.curvature_from = centers_from, curvature_from
        self.name = f"{centers_from.name}-centers+{curvature_from.name}-curvature"

    @property
    def channel_obj_ids(self) -> tuple[int, ...] | None:
        return getattr(self.centers_from, "channel_obj_ids", None)

    @property
    def last_seconds_per_view(self) -> float | None:
        """The network's inference time per view, where one of the sources is a network."""
        for source in (self.centers_from, self.curvature_from):
            seconds = getattr(source, "last_seconds_per_view", None)
            if seconds is not None:
                return seconds
        return None

    def predict(self, scene: Scene) -> Heatmaps:
        centers = self.centers_from.predict(scene)
        curvature = self.curvature_from.predict(scene)
        if centers.im_ids != curvature.im_ids or centers.size != curvature.size:
            raise ValueError(
                f"scene {scene.key}: the centre source gives views {centers.im_ids} at {centers.size}, the"
                f" curvature source {curvature.im_ids} at {curvature.size}"
            )
        return Heatmaps(
            centers.center,
            curvature.curvature.to(centers.center.device),
            centers.channel_obj_ids,
            centers.im_ids,
            curvature.curvature_threshold,  # the curvature's binarisation goes with it
            centers.centers_from_network,  # and the centres' search width with them
            centers.exclusive_channels,
        )
