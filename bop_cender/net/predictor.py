"""The network predictor: stage 1 as the method runs it (``--heatmaps net``), batched over a scene's views.

Reads each view's colour image, runs the U-Net on all views of the scene in batches (CPU or CUDA: the
device given), and returns probabilities (sigmoid of the logits) as :class:`Heatmaps`, the same contract
as the oracle's. :attr:`NetPredictor.last_seconds_per_view` is the inference time of the last scene.
"""

from __future__ import annotations

import time

import numpy as np
import torch

from bop_cender.data.bop_io import load_rgb
from bop_cender.data.types import Scene
from bop_cender.errors import DatasetError
from bop_cender.net.heatmaps import Heatmaps
from bop_cender.net.unet import UNet
from bop_cender.net.weights import NetWeights


@torch.no_grad()
def predict_probabilities(model: UNet, image: torch.Tensor, batch_size: int = 8) -> tuple[torch.Tensor, torch.Tensor]:
    """Sigmoid of ``model``'s logits for ``image (N, 3, H, W)`` in [0, 1], in batches: ``(N, C, H, W)``, ``(N, H, W)``."""
    model.eval()
    centers, curvatures = [], []
    for i in range(0, image.shape[0], batch_size):
        c, k = model(image[i : i + batch_size])
        centers.append(torch.sigmoid(c.float()))
        curvatures.append(torch.sigmoid(k.float()))
    return torch.cat(centers), torch.cat(curvatures)


def scene_rgb(scene: Scene) -> np.ndarray:
    """The colour images of ``scene``'s views as ``(V, H, W, 3)`` uint8 RGB, as the network's inputs are read.

    Raises:
        DatasetError: a view without a colour image, or views of different sizes.
    """
    images = []
    for view in scene.views:
        if view.rgb_path is None:
            raise DatasetError(f"scene {scene.key} image {view.im_id} has no colour image", file=view.source)
        images.append(load_rgb(view.rgb_path))
    if len({im.shape for im in images}) > 1:
        raise DatasetError(f"scene {scene.key}: views of different sizes are not supported")
    return np.stack(images)


def scene_images(scene: Scene, device: torch.device | str = "cpu") -> torch.Tensor:
    """:func:`scene_rgb` as ``(V, 3, H, W)`` float32 in [0, 1] on ``device``."""
    x = torch.from_numpy(scene_rgb(scene)).to(device)
    return x.permute(0, 3, 1, 2).float().div_(255.0).contiguous()


class NetPredictor:
    """Heatmaps from trained weights (:func:`bop_cender.net.weights.load_weights`)."""

    name = "net"

    def __init__(self, weights: NetWeights, device: torch.device | str = "cpu", batch_size: int = 8) -> None:
        self.weights = weights
        self.device = torch.device(device)
        self.model = weights.model.to(self.device).eval()
        self.batch_size = batch_size
        self.last_seconds_per_view: float | None = None

    @property
    def channel_obj_ids(self) -> tuple[int, ...] | None:
        return self.weights.channel_obj_ids

    def predict(self, scene: Scene) -> Heatmaps:
        image = scene_images(scene, self.device)
        t0 = time.perf_counter()
        center, curvature = predict_probabilities(self.model, image, self.batch_size)
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
        self.last_seconds_per_view = (time.perf_counter() - t0) / max(1, image.shape[0])
        return Heatmaps(center, curvature, self.channel_obj_ids, tuple(scene.im_ids))
