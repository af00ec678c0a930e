"""View-space curvature maps: the per-pixel 2-norm of the Prewitt gradients of rendered normals.

The paper's definition (Section 2.1) as docs/design.md states it, stated here once:

- input: camera-space unit normals, 0 on background, channel-last ``(..., H, W, 3)``;
- Prewitt gradients of each of the 3 channels along x and along y with the UNNORMALISED kernels:
  derivative ``[-1, 0, 1]`` along the axis times smoothing ``[1, 1, 1]`` across it (so a step from a
  unit normal to background gives up to 3 per channel);
- curvature = the 2-norm over the 6 gradients at each pixel;
- borders as ``scipy.ndimage.prewitt``'s default mode ``'reflect'`` (``d c b a | a b c d``), which for a
  3-tap kernel is the same as repeating the edge pixel.

Implemented as separable shifted adds over the whole batch at once (docs/performance.md: 7-10x faster than
``conv2d`` on the CPU; this torch code runs on CUDA tensors too).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

#: ``c`` of the heatmaps' ``clip(curvature / c, 0, 1)`` (the targets' default, ``TargetConfig.curvature_scale``,
#: and what stage 3 binarises a pose's own raw curvature with): a unit normal stepping to background gives
#: up to 3 per channel, so 4 keeps silhouettes and sharp creases below saturation.
DEFAULT_CURVATURE_SCALE = 4.0


def curvature(normals: torch.Tensor) -> torch.Tensor:
    """Curvature maps ``(..., H, W)`` of normal maps ``(..., H, W, 3)`` (any leading batch shape).

    Args:
        normals: camera-space unit normals, background 0, float32 (any device).

    Returns:
        Non-negative curvature, same dtype and device.
    """
    if normals.shape[-1] != 3 or normals.dim() < 3:
        raise ValueError(f"expected normals of shape (..., H, W, 3), got {tuple(normals.shape)}")
    lead, (H, W) = normals.shape[:-3], normals.shape[-3:-1]
    n = normals.reshape(-1, H, W, 3).permute(0, 3, 1, 2)  # (N, 3, H, W) view
    padded = F.pad(n.reshape(-1, 1, H, W), (1, 1, 1, 1), mode="replicate").view(-1, 3, H + 2, W + 2)
    return curvature_valid(padded).reshape(*lead, H, W)


def curvature_valid(padded: torch.Tensor) -> torch.Tensor:
    """Curvature ``(N, H-2, W-2)`` of the interior of channel-first normal maps ``(N, 3, H, W)``.

    Every output pixel has its full 3x3 neighbourhood inside the input (no border rule): for a window
    whose outer ring is background this equals the curvature of the whole window, ring left out.
    Channels are taken one at a time into one accumulator (a third of the memory traffic in flight).
    """
    total = None
    for c in range(3):
        ch = padded[:, c]
        rows = ch[:, :-2] + ch[:, 1:-1]  # [1, 1, 1] down the rows ...
        rows += ch[:, 2:]
        gx = rows[..., 2:] - rows[..., :-2]  # ... then [-1, 0, 1] along x
        cols = ch[..., :-2] + ch[..., 1:-1]
        cols += ch[..., 2:]
        gy = cols[:, 2:] - cols[:, :-2]
        if total is None:
            total = gx.mul_(gx)
        else:
            total.addcmul_(gx, gx)
        total.addcmul_(gy, gy)
    return correctly_rounded_sqrt_(total)


def correctly_rounded_sqrt_(x: torch.Tensor) -> torch.Tensor:
    """The IEEE float32 square root of ``x`` (in place where it can), the same bits on every machine.

    Why: torch's CPU ``sqrt`` of float32 goes through MKL's vector maths where torch has MKL, and on an AMD EPYC
    (torch 2.13, AVX2) that was not correctly rounded: 18 % of 2 million random values came out one unit in the last
    place off (``sqrt(3.9999998)`` gave 2.0), against none on an Intel Xeon. The compiled renderer and stage 3's
    loops take the correctly rounded root (:func:`~bop_cender.render.compiled_raster.sqrt32`), so their curvature
    left torch's there, and the own-edge threshold 3.0 flipped pixels. On the CPU the root is therefore taken in
    float64 and rounded once to float32: a float64 root within an ulp rounds to the correctly rounded float32 root
    (the square root of a float32 lies at least 2^-51 relative from any float32 rounding boundary). CUDA's float32
    ``sqrt`` is IEEE already.
    """
    if x.device.type == "cpu":
        return x.copy_(x.double().sqrt_())
    return x.sqrt_()
