"""The network predictor: stage 1 as the method runs it (``--heatmaps net``), batched over a scene's views.

Reads each view's colour image, runs the U-Net on all views of the scene in batches (CPU or CUDA: the
device given), and returns probabilities (sigmoid of the logits) as :class:`Heatmaps`, the same contract
as the oracle's. :attr:`NetPredictor.last_seconds_per_view` is the inference time of the last scene.
"""

from __future__ import annotations

import time
from collections import Counter
from pathlib import Path

import numpy as np
import torch

from bop_cender.data.canvas import read_view_rgb
from bop_cender.data.types import Scene
from bop_cender.errors import DatasetError
from bop_cender.net.heatmaps import Heatmaps, scene_channel_ids
from bop_cender.net.unet import UNet
from bop_cender.net.weights import NetWeights

#: Test-time flips by count: the image dimensions flipped in each pass (-1: left-right, -2: up-down).
TEST_FLIPS: dict[int, tuple[tuple[int, ...], ...]] = {1: ((),), 2: ((), (-1,)), 4: ((), (-1,), (-2,), (-2, -1))}


def check_flips(flips: object) -> None:
    """Raise ValueError unless ``flips`` is a count of :data:`TEST_FLIPS` (an int: True and 2.0 are not)."""
    if type(flips) is not int or flips not in TEST_FLIPS:
        raise ValueError(f"expected one of {sorted(TEST_FLIPS)}, got {flips!r}")


def known_class_mask(
    channel_obj_ids: tuple[int, ...], known_ids: set[int] | frozenset[int], device: torch.device | str = "cpu"
) -> torch.Tensor:
    """``(C,)`` bool: which center channels hold an object id of ``known_ids`` (a factored network's classes are
    restricted to them: :func:`bop_cender.net.unet.center_probabilities`)."""
    return torch.tensor([i in known_ids for i in channel_obj_ids], dtype=torch.bool, device=device)


@torch.no_grad()
def predict_probabilities(
    model: UNet,
    image: torch.Tensor,
    batch_size: int = 8,
    flips: int = 1,
    class_mask: torch.Tensor | None = None,
    compact: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Sigmoid of ``model``'s logits for ``image (N, 3, H, W)`` in [0, 1], in batches: ``(N, C, H, W)``, ``(N, H, W)``.

    ``class_mask`` ``(C,)`` bool: a factored network's classes restricted to these (:meth:`UNet.probabilities`);
    ``compact``: the center maps hold those classes' channels only, ``(N, K, H, W)``.
    ``flips`` (1, 2 or 4, :data:`TEST_FLIPS`): the center maps are the mean of the probabilities of the image and
    of its left-right (2) and up-down flips (4), each flipped back; the curvature map is the image's alone. The
    network is trained with both flips (the appendix's augmentations), so each pass is an equally good estimate
    of the centres and their mean has less noise. Curvature is left alone on purpose: its thin edges, a pixel
    apart between passes, average to values under the binarisation threshold t_b, and stage 3 sees the
    binarised map (measured with the shipped DIMO network on seed 9002 `sim`: 4 passes for both heads raised
    center F1 0.540 -> 0.609 and curvature AP 0.615 -> 0.643 but lowered curvature F1 at t_b 0.444 -> 0.429
    and the end-to-end AR_MSSD<5% 0.682 -> 0.483). The centres alone averaged: more 3D centres found (43 of 70
    within 5 mm against 38), end to end 0.611, so ``run`` uses 1 pass (``heatmaps --test-flips`` offers more).
    """
    check_flips(flips)
    model.eval()
    centers, curvatures = [], []
    for i in range(0, image.shape[0], batch_size):
        batch = image[i : i + batch_size]
        center_sum, curvature = None, None
        for dims in TEST_FLIPS[flips]:
            c, k = model.probabilities(batch.flip(dims) if dims else batch, class_mask, compact)
            if dims:
                c = c.flip(dims)
            else:
                curvature = k
            center_sum = c if center_sum is None else center_sum + c
        centers.append(center_sum / flips)
        curvatures.append(curvature)
    return torch.cat(centers), torch.cat(curvatures)


def scene_rgb(scene: Scene) -> np.ndarray:
    """The colour images of ``scene``'s views as ``(V, H, W, 3)`` uint8 RGB, as the network's inputs are read.

    Raises:
        DatasetError: a view without a colour image, or views of different sizes.
    """
    images = []
    for view in scene.views:
        if view.rgb_path is None:
            folder = Path(view.source).parent if view.source else None  # the scene folder, not its camera file
            raise DatasetError(
                f"scene {scene.key} image {view.im_id} has no colour image (no rgb/ or gray/ folder)", file=folder
            )
        image = read_view_rgb(view)
        if image.shape[:2] != (view.height, view.width):
            raise DatasetError(
                f"scene {scene.key}: image is {image.shape[1]}x{image.shape[0]}, expected {view.width}x{view.height}"
                " (the split's image size)",
                file=view.rgb_path,
                field="size",
            )
        images.append(image)
    sizes = Counter(im.shape for im in images)
    if len(sizes) > 1:  # each as its view says, but the views differ (DIMO reads each view's own size)
        common = sizes.most_common(1)[0][0]
        odd = next(v for v, im in zip(scene.views, images, strict=True) if im.shape != common)
        raise DatasetError(
            f"scene {scene.key}: views of different sizes are not supported: this one is {odd.width}x{odd.height},"
            f" the scene's others {common[1]}x{common[0]}",
            file=odd.rgb_path,
            field="size",
        )
    return np.stack(images)


def scene_images(scene: Scene, device: torch.device | str = "cpu") -> torch.Tensor:
    """:func:`scene_rgb` as ``(V, 3, H, W)`` float32 in [0, 1] on ``device``."""
    x = torch.from_numpy(scene_rgb(scene)).to(device)
    return x.permute(0, 3, 1, 2).float().div_(255.0).contiguous()


class NetPredictor:
    """Heatmaps from trained weights (:func:`bop_cender.net.weights.load_weights`).

    ``known_object_ids``: for a network with factored centers (``tless-factored``), the class softmax is
    restricted to the object ids the scene is known to hold (its GT, as BOP's test targets give them; ``run`` sets
    it from ``CenDerNetConfig.known_object_ids``), so that a part mistaken for a look-alike of another size
    that is not in the image goes to the look-alike that is, and the heatmaps hold those ids' channels only
    (:func:`~bop_cender.net.heatmaps.scene_channel_ids`; the others would be exactly 0). No effect on independent
    channels or without GT.
    ``flips``: test-time flips (:func:`predict_probabilities`; 1: the network alone, as the cards' subsets).
    ``curvature_threshold``: the binarisation threshold its heatmaps carry for stage 3 (``run`` passes
    ``poses.network.t_b`` when set); None: the weights' calibrated one, or stage 3's ``t_b`` without one.
    """

    name = "net"

    def __init__(
        self,
        weights: NetWeights,
        device: torch.device | str = "cpu",
        batch_size: int = 8,
        known_object_ids: bool = True,
        flips: int = 1,
        curvature_threshold: float | None = None,
    ) -> None:
        check_flips(flips)
        self.curvature_threshold = (
            curvature_threshold if curvature_threshold is not None else weights.curvature_threshold
        )
        self.weights = weights
        self.device = torch.device(device)
        self.model = weights.model.to(self.device).eval()
        self.batch_size = batch_size
        self.known_object_ids = known_object_ids
        self.flips = flips
        self.last_seconds_per_view: float | None = None

    @property
    def channel_obj_ids(self) -> tuple[int, ...] | None:
        return self.weights.channel_obj_ids

    def predict(self, scene: Scene) -> Heatmaps:
        image = scene_images(scene, self.device)
        t0 = time.perf_counter()
        ids = self.channel_obj_ids
        class_mask = None
        if self.known_object_ids and self.model.spec.factored_centers and ids is not None:
            kept = scene_channel_ids(ids, {g.obj_id for g in scene.gt})
            if kept != ids:
                class_mask = known_class_mask(ids, set(kept), self.device)
                ids = kept
        center, curvature = predict_probabilities(
            self.model, image, self.batch_size, self.flips, class_mask, compact=class_mask is not None
        )
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
        self.last_seconds_per_view = (time.perf_counter() - t0) / max(1, image.shape[0])
        return Heatmaps(
            center, curvature, ids, tuple(scene.im_ids), self.curvature_threshold, centers_from_network=True,
            exclusive_channels=self.model.spec.factored_centers,
        )  # fmt: skip
