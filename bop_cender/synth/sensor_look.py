"""A foreign camera: what another sensor and its processing make of the same scene (a test look, never trained on).

Why: stage 1 must hold on images it never saw, and a real camera differs from our renderer's sensor model
(:func:`bop_cender.render.shading.apply_sensor`) and from the training augmentations
(:class:`bop_cender.net.augment.AugmentConfig`) in ways neither draws. This look re-images an existing image with
steps that are outside both, each drawn per image from ``--seed`` and the image's name (deterministic):

- exposure: under- or over-exposed by a factor of 0.40-0.60 or 1.6-2.2 in linear light (training draws brightness
  0.7-1.3 in sRGB), clipped at white as a sensor saturates;
- white balance: per-channel gains 0.75-1.25 (green fixed; the synthetic casts stay within 0.85-1.15);
- defocus: a pillbox (disc) of radius 1.0-2.5 px, not the Gaussian of our sensor and of the augmentations;
- a Bayer colour filter (RGGB) and a bilinear demosaic: colour fringes along every edge;
- shot and read noise with row banding (a per-row offset), then the sRGB tone curve (not our 2.2 gamma);
- JPEG compression at quality 35-60 (block and ringing artefacts).

A grey image (one channel) gets the same steps less the white balance and the colour filter.
"""

from __future__ import annotations

import io
import zlib
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image


@dataclass(frozen=True)
class SensorLook:
    """One image's draw of the foreign camera (see the module docstring for the ranges).

    Attributes:
        exposure: linear-light gain.
        white_balance: ``(3,)`` gains on R, G, B (G is 1).
        defocus_px: radius of the pillbox blur in pixels.
        read_noise, shot_noise: standard deviations on the [0, 1] linear image (shot: times sqrt(signal)).
        banding: standard deviation of the per-row offset.
        jpeg_quality: JPEG quality (1-95).
    """

    exposure: float
    white_balance: tuple[float, float, float]
    defocus_px: float
    read_noise: float
    shot_noise: float
    banding: float
    jpeg_quality: int

    @staticmethod
    def draw(rng: np.random.Generator) -> SensorLook:
        dark = rng.random() < 0.5
        exposure = rng.uniform(0.40, 0.60) if dark else rng.uniform(1.6, 2.2)
        red, blue = rng.uniform(0.75, 1.25, 2)
        return SensorLook(
            exposure=float(exposure),
            white_balance=(float(red), 1.0, float(blue)),
            defocus_px=float(rng.uniform(1.0, 2.5)),
            read_noise=float(rng.uniform(0.01, 0.02)),
            shot_noise=float(rng.uniform(0.02, 0.04)),
            banding=float(rng.uniform(0.003, 0.008)),
            jpeg_quality=int(rng.integers(35, 61)),
        )


def look_rng(seed: int, image_name: str) -> np.random.Generator:
    """The draws of one image: a pure function of the seed and the image's name (its path in the dataset)."""
    return np.random.default_rng([seed, zlib.crc32(image_name.encode())])


def apply_sensor_look(image: np.ndarray, look: SensorLook, rng: np.random.Generator) -> np.ndarray:
    """The same view through the foreign camera.

    Args:
        image: uint8 ``(H, W, 3)`` sRGB or ``(H, W)`` grey.
        look: the camera's draw for this image.
        rng: draws the noise.

    Returns:
        uint8 image of the input's shape.
    """
    if image.dtype != np.uint8 or image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] != 3):
        raise ValueError(f"expected a uint8 (H, W) or (H, W, 3) image, got {image.dtype} {image.shape}")
    grey = image.ndim == 2
    srgb = torch.from_numpy(image.astype(np.float32) / 255.0)
    chw = (srgb.unsqueeze(0) if grey else srgb.permute(2, 0, 1)).contiguous()  # (C, H, W)
    linear = _srgb_to_linear(chw) * look.exposure
    if not grey:
        linear = linear * torch.tensor(look.white_balance).view(3, 1, 1)
    linear = _pillbox_blur(linear.clamp(0.0, 1.0), look.defocus_px)
    if not grey:
        linear = _bayer_demosaic(linear)
    noise = torch.from_numpy(rng.standard_normal(linear.shape).astype(np.float32))
    rows = torch.from_numpy(rng.standard_normal((1, linear.shape[1], 1)).astype(np.float32))
    std = torch.sqrt(look.read_noise**2 + look.shot_noise**2 * linear)
    linear = (linear + noise * std + rows * look.banding).clamp(0.0, 1.0)
    out = torch.round(_linear_to_srgb(linear) * 255.0).to(torch.uint8)
    array = out[0].numpy() if grey else out.permute(1, 2, 0).contiguous().numpy()
    return _jpeg_round_trip(array, look.jpeg_quality)


def _srgb_to_linear(x: torch.Tensor) -> torch.Tensor:
    return torch.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def _linear_to_srgb(x: torch.Tensor) -> torch.Tensor:
    return torch.where(x <= 0.0031308, x * 12.92, 1.055 * x.clamp(min=0.0031308) ** (1 / 2.4) - 0.055)


def _pillbox_blur(chw: torch.Tensor, radius: float) -> torch.Tensor:
    """``(C, H, W)`` convolved with a disc of ``radius`` pixels (area-weighted at its rim), borders replicated."""
    r = int(np.ceil(radius))
    offsets = torch.arange(-r, r + 1, dtype=torch.float32)
    dist = torch.sqrt(offsets.view(-1, 1) ** 2 + offsets.view(1, -1) ** 2)
    kernel = (radius + 0.5 - dist).clamp(0.0, 1.0)  # 1 inside, a linear ramp over the rim's pixel
    kernel = (kernel / kernel.sum()).view(1, 1, 2 * r + 1, 2 * r + 1)
    padded = F.pad(chw.unsqueeze(1), (r, r, r, r), mode="replicate")
    return F.conv2d(padded, kernel).squeeze(1)


def _bayer_demosaic(rgb: torch.Tensor) -> torch.Tensor:
    """``(3, H, W)`` sampled through an RGGB colour filter, then filled back by bilinear interpolation."""
    _, H, W = rgb.shape
    yy, xx = torch.meshgrid(torch.arange(H), torch.arange(W), indexing="ij")
    masks = torch.stack([(yy % 2 == 0) & (xx % 2 == 0), (yy + xx) % 2 == 1, (yy % 2 == 1) & (xx % 2 == 1)]).to(
        rgb.dtype
    )  # (3, H, W): where each channel was measured
    kernel = torch.tensor([[0.25, 0.5, 0.25], [0.5, 1.0, 0.5], [0.25, 0.5, 0.25]]).view(1, 1, 3, 3)
    sampled = F.pad((rgb * masks).unsqueeze(1), (1, 1, 1, 1), mode="reflect")
    weight = F.pad(masks.unsqueeze(1), (1, 1, 1, 1), mode="reflect")
    filled = F.conv2d(sampled, kernel) / F.conv2d(weight, kernel).clamp(min=1e-6)
    return torch.where(masks.bool(), rgb, filled.squeeze(1))


def _jpeg_round_trip(image: np.ndarray, quality: int) -> np.ndarray:
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="JPEG", quality=quality)
    buffer.seek(0)
    with Image.open(buffer) as decoded:
        return np.asarray(decoded.convert("L" if image.ndim == 2 else "RGB"))
