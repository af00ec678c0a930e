"""Centre votes (ours, not the paper's): every pixel of a target object points at its object's centre.

Why. The paper's center head must put a peak at the projection of an object's bounding-box centre. For a plate or
a flange that point lies on the part and a local detector finds it; for an L-shaped bracket it lies in the air
inside the L, over the table or another part, where nothing local says "centre". Measured on our T-LESS layout
(the shipped ``tless-factored`` network; per view, instances more than half visible): the map's median value at a
bracket's centre is 0.05-0.08 and a peak within 5 px is found for 0-6 % of them, on test views *and on the
network's own training views*; 30 epochs on 48 views alone (over-fitting them) left it at 0.11 and 4 %, and a
centre-only branch with dilated context changed nothing, while flanges and plates score 0.8-0.97 (every one of the
60 brackets of four test sets was lost end to end). Hough voting does not need the centre to look like anything:
each pixel on the part regresses the offset from itself to the centre, and the votes of all of a part's pixels
pile up there.

The vote head outputs four maps per pixel (:data:`VOTE_CHANNELS`), at the image's resolution:

- ``0``: the logit that the pixel shows a target object with a centre blob in this view (``fg``);
- ``1, 2``: the offset ``(dx, dy)`` from the pixel's centre to its object's projected centre, in units of the
  square root of the object's visible area (so that it does not change with the part's distance or a zoom: a
  convolutional network is translation- but not scale-equivariant);
- ``3``: ``(log(area) - LOG_AREA_MEAN) / LOG_AREA_SCALE``, the object's visible area in pixels, so that each vote
  weighs ``1 / area`` and a part's votes sum to about 1 whatever its size (a peak of 1 where they all agree).

:func:`vote_map` turns them into a class-agnostic center map in [0, 1]: each pixel with ``fg`` above 0.5 casts a
vote of weight ``sigmoid(fg) / area`` at its centre, splatted bilinearly, then blurred by a Gaussian of peak 1 and
standard deviation ``sigma_px``: where all of a part's votes land within a pixel the map reads about 1; spread over
``s`` pixels, about ``sigma^2 / (sigma^2 + s^2)``. :class:`bop_cender.net.unet.UNet` combines it with its center
head's own map (their maximum, or the votes alone: :attr:`bop_cender.net.unet.UNetSpec.vote_mix`).

Targets (:class:`VoteTargets`) are an id map per view (``uint8``: 0 nothing, ``k``: the view's ``k``-th voting
object) and each view's table of ``(x, y, area)``; :func:`dense_vote_targets` makes the four dense maps
``(fg, dx, dy, log(area))`` of a batch in pixels, which the augmentations flip and zoom as vector fields
(:func:`bop_cender.net.augment.augment_with_votes`) and :func:`vote_loss` compares with the head's output.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

#: The vote head's outputs: fg logit, dx, dy, log-area (see the module docstring).
VOTE_CHANNELS = 4
#: The predicted log-area is ``LOG_AREA_MEAN + LOG_AREA_SCALE * output`` (areas of 50 to 50,000 px: log 4-11).
LOG_AREA_MEAN = 7.0
LOG_AREA_SCALE = 2.0
#: Pixels whose predicted ``fg`` probability is at least this vote.
VOTE_MIN_FG = 0.5
#: A voting object covers at most this many ids of a view's id map (``uint8``: 0 is "nothing").
MAX_VOTING_OBJECTS = 255


@dataclass(frozen=True)
class VoteTargets:
    """The voting pixels of a scene's views.

    Attributes:
        ids: ``(V, H, W)`` uint8: 0 where no voting object shows, ``k`` where the view's ``k``-th one does.
        tables: per view, ``(K, 3)`` float32: the ``k``-th voting object's projected centre ``(x, y)`` (continuous
            image coordinates: pixel ``(u, v)``'s centre is ``(u + 0.5, v + 0.5)``) and its visible area (pixels)
            in row ``k - 1``.
    """

    ids: np.ndarray
    tables: tuple[np.ndarray, ...]


def vote_targets(instance: torch.Tensor, centres_xy: np.ndarray, voting: np.ndarray) -> VoteTargets:
    """:class:`VoteTargets` from a render of the pile.

    Args:
        instance: ``(V, H, W)`` index of the object seen at each pixel (-1: none), into the scene's GT list.
        centres_xy: ``(V, M, 2)`` each object's projected centre per view (continuous image coordinates).
        voting: ``(V, M)`` bool: whether object ``m`` votes in view ``v`` (a target object with a centre blob there).

    Raises:
        ValueError: more than :data:`MAX_VOTING_OBJECTS` voting objects in one view.
    """
    inst = instance.detach().cpu().numpy().astype(np.int64)
    V, H, W = inst.shape
    ids = np.zeros((V, H, W), np.uint8)
    tables = []
    for v in range(V):
        members = np.flatnonzero(voting[v])
        if len(members) > MAX_VOTING_OBJECTS:
            raise ValueError(f"{len(members)} voting objects in one view; at most {MAX_VOTING_OBJECTS}")
        lookup = np.zeros(voting.shape[1] + 1, np.int64)  # GT index + 1 -> id (0: not voting)
        lookup[members + 1] = np.arange(1, len(members) + 1)
        ids[v] = lookup[inst[v] + 1]
        area = np.bincount(ids[v].ravel(), minlength=len(members) + 1)[1:]
        table = np.concatenate([centres_xy[v, members], area[:, None]], axis=1).astype(np.float32)
        tables.append(table.reshape(-1, 3))
    return VoteTargets(ids, tuple(tables))


def dense_vote_targets(ids: torch.Tensor, tables: Sequence[np.ndarray]) -> torch.Tensor:
    """``(B, 4, H, W)`` float32 ``(fg, dx, dy, log(area))`` in pixels from id maps ``ids (B, H, W)`` (uint8) and each
    sample's table (:class:`VoteTargets`); 0 wherever ``fg`` is 0."""
    B, H, W = ids.shape
    K = max((len(t) for t in tables), default=0)
    table = torch.zeros((B, K + 1, 3), dtype=torch.float32)
    for b, t in enumerate(tables):
        if len(t):
            table[b, 1 : len(t) + 1] = torch.from_numpy(np.asarray(t, np.float32))
    table = table.to(ids.device)
    idx = ids.long().flatten(1)  # (B, HW)
    per_pixel = torch.gather(table, 1, idx[..., None].expand(-1, -1, 3)).reshape(B, H, W, 3)
    fg = (ids > 0).float()
    u = torch.arange(W, dtype=torch.float32, device=ids.device) + 0.5
    v = torch.arange(H, dtype=torch.float32, device=ids.device) + 0.5
    dx = (per_pixel[..., 0] - u) * fg
    dy = (per_pixel[..., 1] - v[:, None]) * fg
    log_area = torch.log(per_pixel[..., 2].clamp_min(1.0)) * fg
    return torch.stack([fg, dx, dy, log_area], dim=1)


def vote_loss(raw: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """The vote head's loss: BCE-with-logits of ``fg`` over every pixel, plus, over the pixels whose ``fg`` target
    is above 0.5, the L1 of the offsets (in units of the square root of the object's area) and of the scaled
    log-area. ``raw (B, 4, H, W)``: the head's output; ``target``: :func:`dense_vote_targets` (augmented)."""
    fg_target = target[:, 0]
    loss = F.binary_cross_entropy_with_logits(raw[:, 0], fg_target)
    mask = fg_target > 0.5
    if bool(mask.any()):
        offsets = raw[:, 1:3].permute(0, 2, 3, 1)[mask]
        size = torch.exp(0.5 * target[:, 3][mask])[:, None]  # sqrt(area): target[:, 3] is log(area)
        offsets_target = target[:, 1:3].permute(0, 2, 3, 1)[mask] / size
        loss = loss + F.l1_loss(offsets, offsets_target)
        area_target = (target[:, 3][mask] - LOG_AREA_MEAN) / LOG_AREA_SCALE
        loss = loss + F.l1_loss(raw[:, 3][mask], area_target)
    return loss


def vote_map(raw: torch.Tensor, sigma_px: float) -> torch.Tensor:
    """``(B, 1, H, W)`` class-agnostic center map in [0, 1] from the vote head's ``raw (B, 4, H, W)`` output.

    Each pixel whose ``fg`` probability is at least :data:`VOTE_MIN_FG` votes with weight ``p / area`` at
    ``pixel + offset``, splatted bilinearly onto the pixel grid; the sum is blurred by a Gaussian of peak 1 and
    standard deviation ``sigma_px`` (pixels) and clipped to 1.
    """
    raw = raw.float()
    B, _, H, W = raw.shape
    out = torch.zeros(B * H * W, dtype=torch.float32, device=raw.device)
    # Only the pixels that vote are read further: a few percent of a view (7 % on a T-LESS test view), so the
    # offsets, areas and the four bilinear corners cost that share of the full image (63 -> 28-34 ms per 720x540
    # view on 2 CPU cores, most of the rest the blur: ``python scripts/bench_net.py``, its post-processing row).
    p_all = torch.sigmoid(raw[:, 0])
    b, y, x = torch.nonzero(p_all >= VOTE_MIN_FG, as_tuple=True)
    if len(b):
        p = p_all[b, y, x]
        picked = raw[b, :, y, x]  # (N, 4)
        log_area = LOG_AREA_MEAN + LOG_AREA_SCALE * picked[:, 3].clamp(-6.0, 6.0)
        weight = p * torch.exp(-log_area)
        size = torch.exp(0.5 * log_area)  # sqrt(area): the offsets' unit
        # the vote's position in grid units (pixel u's centre is at u): pixel + offset
        gx = x.float() + picked[:, 1] * size
        gy = y.float() + picked[:, 2] * size
        # non-finite votes are dropped, and votes far outside the view before their conversion to integers
        finite = (gx > -2) & (gx < W + 1) & (gy > -2) & (gy < H + 1) & (weight > 0)
        b, gx, gy, weight = b[finite], gx[finite], gy[finite], weight[finite]
        x0, y0 = torch.floor(gx), torch.floor(gy)
        fx, fy = gx - x0, gy - y0
        x0, y0 = x0.long(), y0.long()
        for ox, oy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
            xi, yi = x0 + ox, y0 + oy
            inside = (xi >= 0) & (xi < W) & (yi >= 0) & (yi < H)
            out.index_add_(0, (b * (H * W) + yi * W + xi)[inside], (weight * w)[inside])
    return gaussian_peak_blur(out.view(B, 1, H, W), sigma_px).clamp_(0.0, 1.0)


def gaussian_peak_blur(x: torch.Tensor, sigma_px: float) -> torch.Tensor:
    """``x (B, 1, H, W)`` convolved with ``exp(-r^2 / (2 sigma^2))`` (peak 1, not unit sum), separably, zero outside."""
    radius = max(1, math.ceil(3.0 * sigma_px))
    t = torch.arange(-radius, radius + 1, dtype=torch.float32, device=x.device)
    k = torch.exp(-(t**2) / (2.0 * sigma_px**2))
    x = F.conv2d(x, k.view(1, 1, 1, -1), padding=(0, radius))
    return F.conv2d(x, k.view(1, 1, -1, 1), padding=(radius, 0))
