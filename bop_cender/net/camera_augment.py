"""A camera augmentation beyond the paper's: what another camera and its processing do to an image (issue 42's lever
"photometric augmentation stronger than the paper's").

Why: stage 1 loses a fifth to a half of its accuracy on images of a look it never saw (``results/robustness/``).
The paper's augmentations (:mod:`bop_cender.net.augment`) keep the tone curve, the colour balance and the focus of
our renderer: their blur (sigma 0.05 px) is all but the identity, their noise is one grey level of white noise. A
real camera defocuses, casts colour, bends the tone curve, loses resolution and adds signal-dependent noise. This
augmentation draws each of these per sample, on the image only (the targets are geometry and do not change):

- colour cast: red and blue gains U(0.85, 1.15) relative to green (probability 0.5);
- tone curve: ``x ** gamma``, gamma drawn log-uniformly in [1/1.6, 1.6] (probability 0.5);
- defocus: a Gaussian blur of sigma U(0.5, 1.5) px (probability 0.5);
- resolution loss: down-sampled by U(0.4, 0.8) and up again, bilinear (probability 0.3);
- noise: shot noise ``a * sqrt(x)`` with a U(0, 0.05) plus read noise U(0, 0.02), per pixel and channel
  (probability 0.5);
- grey: the image replaced by its luma on every channel (probability 0.1): colour carries no geometry.

What it leaves to the test looks (``bop_cender/synth/sensor_look.py``, never trained on): exposures beyond 0.6 / 1.6,
a disc (pillbox) defocus, a Bayer mosaic and demosaic, row banding, the sRGB curve, JPEG blocks.

Shapes: ``image`` ``(B, 3, H, W)`` RGB in [0, 1]; the output has its shape, dtype and device. Every random value
is drawn from the CPU ``torch.Generator`` passed in, in one table per batch (the stream does not depend on which
operations apply), so a seed gives the same images on CPU and CUDA up to float rounding.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
import torch.nn.functional as F

from bop_cender.net.augment import grayscale

# Columns of the per-sample table of uniform draws.
(_CAST_ON, _RED, _BLUE, _TONE_ON, _GAMMA, _BLUR_ON, _SIGMA, _LOWRES_ON, _LOWRES, _NOISE_ON, _SHOT, _READ,
 _GREY_ON) = range(13)  # fmt: skip
_NUM_DRAWS = 13

CAST_P, CAST_GAIN = 0.5, (0.85, 1.15)
TONE_P, GAMMA_MAX = 0.5, 1.6
BLUR_P, BLUR_SIGMA = 0.5, (0.5, 1.5)
LOWRES_P, LOWRES_FACTOR = 0.3, (0.4, 0.8)
NOISE_P, SHOT_NOISE, READ_NOISE = 0.5, 0.05, 0.02
GREY_P = 0.1
#: Half-width of the blur kernel: 3 sigma of the widest blur.
_BLUR_RADIUS = math.ceil(3 * BLUR_SIGMA[1])


def camera_augment(image: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """A new ``(B, 3, H, W)`` image in [0, 1], each sample through its own drawn camera (module docstring).

    Raises:
        ValueError: ``image`` not ``(B, 3, H, W)`` floating point, or a generator that is not on the CPU.
    """
    if image.dim() != 4 or image.shape[1] != 3 or not image.is_floating_point():
        raise ValueError(f"image must be a floating-point (B, 3, H, W) tensor, got {tuple(image.shape)} {image.dtype}")
    if generator.device.type != "cpu":
        raise ValueError(f"generator must be a CPU torch.Generator, got one on {generator.device}")
    B = image.shape[0]
    if image.numel() == 0:
        return image.clone()
    u = torch.rand((B, _NUM_DRAWS), generator=generator, dtype=torch.float64).to(image.device)
    noise = torch.randn(image.shape, generator=generator, dtype=image.dtype).to(image.device)

    def uniform(col: int, lo: float, hi: float) -> torch.Tensor:
        return (lo + (hi - lo) * u[:, col]).to(image.dtype)

    def where_drawn(img: torch.Tensor, col: int, p: float, op: Callable[[torch.Tensor, torch.Tensor], torch.Tensor]):
        """``img`` with ``op(img[on], on)`` on the samples ``on`` whose coin in column ``col`` fell under ``p`` (only
        those are computed)."""
        on = (u[:, col] < p).nonzero().flatten()
        if on.numel() == 0:
            return img
        out = img.clone()
        out[on] = op(img[on], on)
        return out

    gains = torch.stack([uniform(_RED, *CAST_GAIN), torch.ones_like(u[:, 0], dtype=image.dtype),
                         uniform(_BLUE, *CAST_GAIN)], dim=1)  # fmt: skip
    gamma = torch.exp(uniform(_GAMMA, -math.log(GAMMA_MAX), math.log(GAMMA_MAX)))
    sigma, factor = uniform(_SIGMA, *BLUR_SIGMA), uniform(_LOWRES, *LOWRES_FACTOR)
    shot, read = uniform(_SHOT, 0.0, SHOT_NOISE), uniform(_READ, 0.0, READ_NOISE)

    def noisy(x: torch.Tensor, on: torch.Tensor) -> torch.Tensor:
        std = shot[on, None, None, None] * x.sqrt() + read[on, None, None, None]  # shot noise grows with the signal
        return (x + std * noise[on]).clamp(0.0, 1.0)

    img = where_drawn(image, _CAST_ON, CAST_P, lambda x, on: (x * gains[on, :, None, None]).clamp(0.0, 1.0))
    img = where_drawn(img, _TONE_ON, TONE_P, lambda x, on: x.clamp_min(1e-6) ** gamma[on, None, None, None])
    img = where_drawn(img, _BLUR_ON, BLUR_P, lambda x, on: gaussian_blur_per_sample(x, sigma[on]))
    img = where_drawn(img, _LOWRES_ON, LOWRES_P, lambda x, on: _low_resolution(x, factor[on]))
    img = where_drawn(img, _NOISE_ON, NOISE_P, noisy)
    img = where_drawn(img, _GREY_ON, GREY_P, lambda x, on: grayscale(x).expand_as(x))
    return img if img is not image else image.clone()


def gaussian_blur_per_sample(image: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """``(B, C, H, W)`` blurred by a separable Gaussian of ``sigma`` ``(B,)`` px per sample, reflected borders
    (replicated where the image is smaller than the kernel's half-width)."""
    B, C, H, W = image.shape
    r = _BLUR_RADIUS
    x = torch.arange(-r, r + 1, dtype=image.dtype, device=image.device)
    k = torch.exp(-0.5 * (x.view(1, -1) / sigma.view(-1, 1)) ** 2)
    k = (k / k.sum(dim=1, keepdim=True)).repeat_interleave(C, dim=0)  # (B*C, 2r+1)
    mode = "reflect" if min(H, W) > r else "replicate"
    flat = F.pad(image.reshape(1, B * C, H, W), (r, r, r, r), mode=mode)
    out = F.conv2d(flat, k.view(B * C, 1, 1, -1), groups=B * C)
    out = F.conv2d(out, k.view(B * C, 1, -1, 1), groups=B * C)
    return out.view(B, C, H, W)


def _low_resolution(image: torch.Tensor, factor: torch.Tensor) -> torch.Tensor:
    """``(B, C, H, W)`` down-sampled by ``factor`` ``(B,)`` (bilinear, antialiased) and up again to ``H x W``."""
    H, W = image.shape[-2:]
    out = torch.empty_like(image)
    for b in range(image.shape[0]):  # one resize per sample of a batch (a handful), never per pixel
        size = (max(1, round(H * float(factor[b]))), max(1, round(W * float(factor[b]))))
        small = F.interpolate(image[b : b + 1], size=size, mode="bilinear", align_corners=False, antialias=True)
        out[b : b + 1] = F.interpolate(small, size=(H, W), mode="bilinear", align_corners=False)
    return out.clamp(0.0, 1.0)
