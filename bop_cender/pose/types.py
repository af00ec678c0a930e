"""What flows between stage 3's steps: an object's target, a placed object, the scene's cameras and cost maps."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch


@dataclass(frozen=True)
class PoseTarget:
    """What stage 3 fits one object to: its 3D centre ``(3,)`` (world, mm), per-view scores ``(V,)``, the object ids
    it may be and, for the centre term (``poses.center_weight``), the center heatmaps ``(V, H, W)`` it was found in
    (None: no centre term)."""

    center: np.ndarray
    view_scores: np.ndarray
    obj_ids: tuple[int, ...]
    center_map: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class PlacedObject:
    """One optimised object: ``T_world_model (4, 4)`` (mm), its final cost (pixels) and the evaluations it took."""

    obj_id: int
    T_world_model: np.ndarray
    cost: float
    evaluations: int


@dataclass
class SceneCameras:
    """The scene's cameras as the cost needs them: ``Ks (V, 3, 3)``, ``T_cam_world (V, 4, 4)``, image size."""

    Ks: np.ndarray
    T_cam_world: np.ndarray
    height: int
    width: int

    def downscaled(self, factor: int) -> SceneCameras:
        """The same cameras with images ``factor`` times smaller: continuous image points divide by ``factor``
        (so pixel centres stay at ``u + 0.5``), image size rounded up."""
        K = self.Ks.copy()
        K[:, :2] /= factor
        return SceneCameras(K, self.T_cam_world, -(-self.height // factor), -(-self.width // factor))


@dataclass
class CostMaps:
    """Distance maps ``dist (V, H, W)`` (pixels) of one resolution, the cameras that go with them and, at full
    resolution, the binarised target curvature ``edges (V, H, W)`` they were made from."""

    cameras: SceneCameras
    dist: torch.Tensor
    edges: torch.Tensor | None = None
