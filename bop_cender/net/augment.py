"""Training augmentations of the CenDerNet paper's appendix, on batched tensors, seeded.

Why these: the network predicts per-view object-centre heatmaps and curvature maps, not a pose, so an
augmentation that changes the pose (a horizontal or vertical flip, a zoom) is allowed as long as the
targets undergo the same change (paper, appendix). Geometric operations (flips, scale) therefore apply
to the image *and* both targets; photometric operations (brightness, contrast, hue, blur, noise,
sharpness) to the image only.

Shapes: ``image`` ``(B, 3, H, W)`` RGB in [0, 1]; ``center`` ``(B, C, H, W)`` in [0, 1] (one shared
channel or one per object); ``curvature`` ``(B, H, W)`` in [0, 1]. The outputs have the same shapes,
dtypes and device as the inputs, which are left untouched.

Randomness: every random value is drawn per sample from the ``torch.Generator`` passed in, a CPU
generator, on the CPU, then moved to the inputs' device, so that the same seed gives the same
parameters (and, up to float rounding, the same result) on CPU and CUDA. The operations run in this
order: flips, scale, then brightness, contrast, hue, blur, noise, sharpness (the paper's list order);
each photometric result is clipped to [0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch
import torch.nn.functional as F

# Columns of the per-sample table of uniform draws (one row per sample, drawn all at once).
_HFLIP, _VFLIP, _SCALE, _BRIGHTNESS, _CONTRAST, _HUE, _BLUR, _NOISE, _SHARP_ON, _SHARP = range(10)
_NUM_DRAWS = 10

# ITU-R BT.601 luma weights, the usual grayscale of a contrast adjustment.
_LUMA = (0.299, 0.587, 0.114)


@dataclass(frozen=True)
class AugmentConfig:
    """Which augmentations run and how strongly; the defaults are the paper's appendix.

    Ranges ``(lo, hi)`` are drawn uniformly per sample; probabilities ``p`` decide per sample whether an
    operation applies.

    Attributes:
        hflip_p: probability of a horizontal (left-right) flip of image and targets (paper: 0.5).
        vflip_p: probability of a vertical (up-down) flip of image and targets (paper: 0.5).
        scale: zoom factor range (paper: U(1.0, 1.25)); image and targets are zoomed about the image
            centre by the same per-sample factor and cropped back to ``H x W`` (bilinear), so a point at
            distance ``r`` from the centre moves to ``s * r``. A factor below 1 would zoom out and fill
            the border with zeros.
        brightness: multiplicative brightness factor range (paper: U(0.7, 1.3)).
        contrast: contrast factor range (paper: U(0.7, 1.3)): the image is blended with the mean of its
            grayscale, ``mean + f * (image - mean)``.
        hue: hue shift range as a fraction of the hue circle (paper: U(-0.1, 0.1)), done in HSV.
        blur_p: probability of a Gaussian blur (paper: 0.5).
        blur_kernel: odd side of the Gaussian blur kernel in pixels (paper: 3).
        blur_sigma: standard deviation of the Gaussian blur in pixels (paper: 0.05, which is all but the
            identity: the neighbours' weight is ``exp(-200)``; kept as the paper states it).
        noise_p: probability of additive Gaussian noise (paper: 0.5).
        noise_std: standard deviation of that noise on the [0, 1] image. The paper gives none; 0.02 (about
            5 of 255 grey levels) is ours: visible sensor-like grain that does not drown thin edges.
        sharpness_p: probability of a sharpness change (paper: 0.5).
        sharpness: sharpness factor range (paper: U(0.5, 1.5)); the image is blended with a 3x3-smoothed
            copy: 0 gives the smoothed image, 1 the original, 2 a sharpened one; border pixels are kept.
    """

    hflip_p: float = 0.5
    vflip_p: float = 0.5
    scale: tuple[float, float] = (1.0, 1.25)
    brightness: tuple[float, float] = (0.7, 1.3)
    contrast: tuple[float, float] = (0.7, 1.3)
    hue: tuple[float, float] = (-0.1, 0.1)
    blur_p: float = 0.5
    blur_kernel: int = 3
    blur_sigma: float = 0.05
    noise_p: float = 0.5
    noise_std: float = 0.02
    sharpness_p: float = 0.5
    sharpness: tuple[float, float] = (0.5, 1.5)

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name.endswith("_p") and not 0.0 <= value <= 1.0:
                raise ValueError(f"AugmentConfig.{f.name} must be a probability in [0, 1], got {value}")
            if isinstance(value, tuple) and (len(value) != 2 or value[0] > value[1]):
                raise ValueError(f"AugmentConfig.{f.name} must be a range (lo, hi) with lo <= hi, got {value}")
        if self.blur_kernel < 1 or self.blur_kernel % 2 == 0:
            raise ValueError(f"AugmentConfig.blur_kernel must be odd and positive, got {self.blur_kernel}")
        if self.blur_sigma <= 0:
            raise ValueError(f"AugmentConfig.blur_sigma must be positive, got {self.blur_sigma}")
        if self.noise_std < 0:
            raise ValueError(f"AugmentConfig.noise_std must be non-negative, got {self.noise_std}")
        if self.scale[0] <= 0:
            raise ValueError(f"AugmentConfig.scale must be positive, got {self.scale}")

    @staticmethod
    def none() -> AugmentConfig:
        """Every augmentation off: :func:`augment` returns copies of its inputs."""
        return AugmentConfig(
            hflip_p=0.0,
            vflip_p=0.0,
            scale=(1.0, 1.0),
            brightness=(1.0, 1.0),
            contrast=(1.0, 1.0),
            hue=(0.0, 0.0),
            blur_p=0.0,
            noise_p=0.0,
            sharpness_p=0.0,
            sharpness=(1.0, 1.0),
        )


def augment(
    image: torch.Tensor,
    center: torch.Tensor,
    curvature: torch.Tensor,
    config: AugmentConfig,
    generator: torch.Generator,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Augment a batch: the same random flips and zoom for image and targets, photometric changes to the image
    (:func:`augment_with_votes` without votes)."""
    image, center, curvature, _ = augment_with_votes(image, center, curvature, None, config, generator)
    return image, center, curvature


def augment_with_votes(
    image: torch.Tensor,
    center: torch.Tensor,
    curvature: torch.Tensor,
    votes: torch.Tensor | None,
    config: AugmentConfig,
    generator: torch.Generator,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Augment a batch: the same random flips and zoom for image and targets, photometric changes to the image.

    Args:
        image: ``(B, 3, H, W)`` float RGB in [0, 1].
        center: ``(B, C, H, W)`` float center heatmaps in [0, 1].
        curvature: ``(B, H, W)`` float curvature maps in [0, 1].
        votes: ``(B, 4, H, W)`` the centre votes' dense targets ``(fg, dx, dy, log(area))`` in pixels
            (:func:`~bop_cender.net.votes.dense_vote_targets`), or None. They are vector fields: a flip negates
            the flipped offset, a zoom by ``s`` multiplies the offsets by ``s`` and the area by ``s^2``; the
            zoom's bilinear resampling is normalised by the resampled ``fg`` (offsets and areas are the mean of
            the voting pixels' around a point, never mixed with the background's zeros).
        config: which augmentations and how strongly (:class:`AugmentConfig`; the defaults are the paper's).
        generator: a CPU ``torch.Generator``; all random values are drawn from it, per sample.

    Returns:
        New ``(image, center, curvature, votes)`` tensors of the input shapes, dtypes and device (``votes`` None
        where none was given); the inputs are not modified.

    Raises:
        ValueError: a tensor of the wrong shape, dtype or device (the message names it), or a generator
            that is not on the CPU.
    """
    _validate(image, center, curvature, generator)
    if votes is not None and (votes.dim() != 4 or votes.shape[1] != 4 or votes.shape[0] != image.shape[0]
                              or votes.shape[-2:] != image.shape[-2:] or votes.device != image.device):  # fmt: skip
        raise ValueError(f"votes must be (B, 4, H, W) of the image's B, H, W and device, got {tuple(votes.shape)}")
    if image.numel() == 0:  # an empty batch (or image): nothing to augment, nothing drawn
        return image.clone(), center.clone(), curvature.clone(), None if votes is None else votes.clone()
    B = image.shape[0]
    device = image.device
    # One table of uniforms, always drawn whole, so that the stream does not depend on the config.
    u = torch.rand((B, _NUM_DRAWS), generator=generator, dtype=torch.float64)

    def coin(col: int, p: float) -> torch.Tensor:
        return (u[:, col] < p).to(device)

    def uniform(col: int, lo_hi: tuple[float, float]) -> torch.Tensor:
        lo, hi = lo_hi
        return (lo + (hi - lo) * u[:, col]).to(device=device, dtype=image.dtype)

    img, ctr, curv = image.clone(), center.clone(), curvature.unsqueeze(1).clone()
    vot = None if votes is None else votes.clone()

    # Geometric: image and targets alike.
    if config.hflip_p > 0:
        flip = coin(_HFLIP, config.hflip_p)
        img, ctr, curv = (_flip_where(x, flip, dim=-1) for x in (img, ctr, curv))
        if vot is not None:
            vot = _flip_votes(vot, flip, dim=-1)
    if config.vflip_p > 0:
        flip = coin(_VFLIP, config.vflip_p)
        img, ctr, curv = (_flip_where(x, flip, dim=-2) for x in (img, ctr, curv))
        if vot is not None:
            vot = _flip_votes(vot, flip, dim=-2)
    if config.scale != (1.0, 1.0):
        s = uniform(_SCALE, config.scale)
        img, ctr, curv = (zoom_about_centre(x, s) for x in (img, ctr, curv))
        img = img.clamp(0.0, 1.0)  # bilinear stays in range; this only removes rounding
        if vot is not None:
            vot = _zoom_votes(vot, s)

    # Photometric: the image only.
    if config.brightness != (1.0, 1.0):
        img = adjust_brightness(img, uniform(_BRIGHTNESS, config.brightness))
    if config.contrast != (1.0, 1.0):
        img = adjust_contrast(img, uniform(_CONTRAST, config.contrast))
    if config.hue != (0.0, 0.0):
        img = adjust_hue(img, uniform(_HUE, config.hue))
    if config.blur_p > 0:
        img = _where(coin(_BLUR, config.blur_p), gaussian_blur(img, config.blur_kernel, config.blur_sigma), img)
    if config.noise_p > 0 and config.noise_std > 0:
        noise = torch.randn(img.shape, generator=generator, dtype=img.dtype).to(device)
        noisy = (img + config.noise_std * noise).clamp(0.0, 1.0)
        img = _where(coin(_NOISE, config.noise_p), noisy, img)
    if config.sharpness_p > 0 and config.sharpness != (1.0, 1.0):
        sharp = adjust_sharpness(img, uniform(_SHARP, config.sharpness))
        img = _where(coin(_SHARP_ON, config.sharpness_p), sharp, img)

    return img, ctr, curv.squeeze(1), vot


def _flip_votes(votes: torch.Tensor, mask: torch.Tensor, dim: int) -> torch.Tensor:
    """Vote targets ``(B, 4, H, W)`` flipped along ``dim`` (-1: left-right, -2: up-down) where ``mask (B,)``, the
    offset along that axis negated."""
    flipped = votes.flip(dim)
    flipped[:, 1 if dim == -1 else 2].neg_()
    return _where(mask, flipped, votes)


def _zoom_votes(votes: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """Vote targets ``(B, 4, H, W)`` zoomed about the centre by ``scale (B,)``: offsets times ``s``, log-area plus
    ``2 log s``, resampled as the mean over the voting pixels (normalised by the resampled ``fg``)."""
    z = zoom_about_centre(votes, scale)
    fg = z[:, :1]
    inside = fg > 1e-6
    values = torch.where(inside, z[:, 1:] / fg.clamp_min(1e-6), torch.zeros_like(z[:, 1:]))
    s = scale.view(-1, 1, 1)
    values = torch.stack([values[:, 0] * s, values[:, 1] * s, values[:, 2] + 2.0 * torch.log(s)], dim=1)
    return torch.cat([fg, values * inside], dim=1)


def zoom_about_centre(x: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """``(B, C, H, W)`` zoomed by ``scale`` ``(B,)`` about the image centre, cropped back to ``H x W``.

    Bilinear; output pixel centre ``p`` samples the input at ``centre + (p - centre) / s``, so a point at
    distance ``r`` from the centre ends up at ``s * r``. Outside the input (only when ``s < 1``) is zero.
    """
    B = x.shape[0]
    theta = torch.zeros((B, 2, 3), dtype=x.dtype, device=x.device)
    theta[:, 0, 0] = 1.0 / scale
    theta[:, 1, 1] = 1.0 / scale
    grid = F.affine_grid(theta, list(x.shape), align_corners=False)
    return F.grid_sample(x, grid, mode="bilinear", padding_mode="zeros", align_corners=False)


def adjust_brightness(image: torch.Tensor, factor: torch.Tensor) -> torch.Tensor:
    """``clip(image * factor)``, ``factor`` ``(B,)``."""
    return (image * factor.view(-1, 1, 1, 1)).clamp(0.0, 1.0)


def adjust_contrast(image: torch.Tensor, factor: torch.Tensor) -> torch.Tensor:
    """Blend with the per-sample mean grayscale: ``clip(mean + factor * (image - mean))``, ``factor`` ``(B,)``."""
    mean = grayscale(image).mean(dim=(-3, -2, -1), keepdim=True)
    return (mean + factor.view(-1, 1, 1, 1) * (image - mean)).clamp(0.0, 1.0)


def adjust_hue(image: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
    """Rotate the hue by ``shift`` ``(B,)`` fractions of the hue circle (HSV; saturation and value kept)."""
    h, s, v = rgb_to_hsv(image).unbind(dim=-3)
    h = torch.remainder(h + shift.view(-1, 1, 1), 1.0)
    return hsv_to_rgb(torch.stack((h, s, v), dim=-3)).clamp(0.0, 1.0)


def gaussian_blur(image: torch.Tensor, kernel: int, sigma: float) -> torch.Tensor:
    """Separable Gaussian blur of ``(B, C, H, W)``, side ``kernel`` (odd), std ``sigma`` px, reflected borders."""
    r = kernel // 2
    if r == 0:
        return image.clone()
    x = torch.arange(-r, r + 1, dtype=torch.float64)
    k = torch.exp(-0.5 * (x / sigma) ** 2)
    k = (k / k.sum()).to(device=image.device, dtype=image.dtype)
    C = image.shape[1]
    padded = F.pad(image, (r, r, r, r), mode="reflect" if min(image.shape[-2:]) > r else "replicate")
    out = F.conv2d(padded, k.view(1, 1, 1, -1).expand(C, 1, 1, -1), groups=C)
    return F.conv2d(out, k.view(1, 1, -1, 1).expand(C, 1, -1, 1), groups=C)


def adjust_sharpness(image: torch.Tensor, factor: torch.Tensor) -> torch.Tensor:
    """Blend ``(B, C, H, W)`` with a 3x3-smoothed copy: ``clip(smooth + factor * (image - smooth))``.

    The smoothing kernel is ``[[1, 1, 1], [1, 5, 1], [1, 1, 1]] / 13`` (the usual sharpness definition);
    border pixels keep their values. ``factor`` ``(B,)``: 0 smoothed, 1 original, above 1 sharpened.
    """
    B, C, H, W = image.shape
    if H < 3 or W < 3:
        return image.clone()
    k = torch.ones((3, 3), dtype=image.dtype, device=image.device)
    k[1, 1] = 5.0
    k = (k / k.sum()).view(1, 1, 3, 3).expand(C, 1, 3, 3)
    smooth = image.clone()
    smooth[..., 1:-1, 1:-1] = F.conv2d(image, k, groups=C)
    return (smooth + factor.view(-1, 1, 1, 1) * (image - smooth)).clamp(0.0, 1.0)


def grayscale(image: torch.Tensor) -> torch.Tensor:
    """``(..., 3, H, W)`` RGB to ``(..., 1, H, W)`` luma (BT.601 weights)."""
    w = torch.tensor(_LUMA, dtype=image.dtype, device=image.device).view(3, 1, 1)
    return (image * w).sum(dim=-3, keepdim=True)


def rgb_to_hsv(image: torch.Tensor) -> torch.Tensor:
    """``(..., 3, H, W)`` RGB in [0, 1] to HSV, every channel in [0, 1] (hue as a fraction of the circle)."""
    r, g, b = image.unbind(dim=-3)
    maxc, argmax = image.max(dim=-3)
    minc = image.min(dim=-3).values
    delta = maxc - minc
    safe_delta = torch.where(delta > 0, delta, torch.ones_like(delta))
    # Hue sector (0 to 6) from whichever channel is the largest.
    h = torch.where(
        argmax == 0,
        torch.remainder((g - b) / safe_delta, 6.0),
        torch.where(argmax == 1, (b - r) / safe_delta + 2.0, (r - g) / safe_delta + 4.0),
    )
    h = torch.where(delta > 0, h / 6.0, torch.zeros_like(h))
    s = torch.where(maxc > 0, delta / torch.where(maxc > 0, maxc, torch.ones_like(maxc)), torch.zeros_like(maxc))
    return torch.stack((h, s, maxc), dim=-3)


def hsv_to_rgb(hsv: torch.Tensor) -> torch.Tensor:
    """``(..., 3, H, W)`` HSV (every channel in [0, 1]) to RGB in [0, 1].

    Channel ``n`` (5 for red, 3 for green, 1 for blue) is ``v - v s clip(min(k, 4 - k), 0, 1)`` with
    ``k = (n + 6 h) mod 6``.
    """
    h, s, v = hsv.unbind(dim=-3)
    n = torch.tensor((5.0, 3.0, 1.0), dtype=hsv.dtype, device=hsv.device).view(3, 1, 1)
    k = torch.remainder(n + 6.0 * h.unsqueeze(-3), 6.0)
    ramp = torch.minimum(k, 4.0 - k).clamp(0.0, 1.0)
    return v.unsqueeze(-3) * (1.0 - s.unsqueeze(-3) * ramp)


def _flip_where(x: torch.Tensor, mask: torch.Tensor, dim: int) -> torch.Tensor:
    """``x`` flipped along ``dim`` for the samples where ``mask`` ``(B,)`` is true."""
    return _where(mask, x.flip(dim), x)


def _where(mask: torch.Tensor, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Per sample: ``a`` where ``mask`` ``(B,)`` is true, else ``b``."""
    return torch.where(mask.view(-1, *([1] * (a.dim() - 1))), a, b)


def _validate(image: torch.Tensor, center: torch.Tensor, curvature: torch.Tensor, generator: torch.Generator) -> None:
    if image.dim() != 4 or image.shape[1] != 3:
        raise ValueError(f"image must be (B, 3, H, W), got {tuple(image.shape)}")
    B, _, H, W = image.shape
    if center.dim() != 4 or center.shape[0] != B or tuple(center.shape[2:]) != (H, W):
        raise ValueError(f"center must be (B, C, H, W) = ({B}, C, {H}, {W}) like image, got {tuple(center.shape)}")
    if tuple(curvature.shape) != (B, H, W):
        raise ValueError(f"curvature must be (B, H, W) = ({B}, {H}, {W}) like image, got {tuple(curvature.shape)}")
    for name, t in (("image", image), ("center", center), ("curvature", curvature)):
        if not t.is_floating_point():
            raise ValueError(f"{name} must be a floating-point tensor, got {t.dtype}")
        if t.device != image.device:
            raise ValueError(f"{name} is on {t.device} but image is on {image.device}")
    if generator.device.type != "cpu":
        raise ValueError(f"generator must be a CPU torch.Generator, got one on {generator.device}")
