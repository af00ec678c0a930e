"""Contact sheets: one PNG per synthetic scene so a person can look at what was generated.

Rows are views; columns are RGB, depth (colour-mapped), instance masks and the GT curvature map.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from bop_cender.data.bop_io import write_image
from bop_cender.synth.imaging import ViewBuffers

#: Curvature values at or above this show as white (a unit-normal step gives up to ~4).
CURVATURE_DISPLAY_MAX = 3.0


def _depth_rgb(depth: np.ndarray) -> np.ndarray:
    valid = depth > 0
    out = np.zeros((*depth.shape, 3), np.uint8)
    if valid.any():
        lo, hi = np.percentile(depth[valid], [1, 99])
        norm = np.clip((depth - lo) / max(hi - lo, 1e-6), 0, 1)
        coloured = cv2.applyColorMap((255 - norm * 255).astype(np.uint8), cv2.COLORMAP_TURBO)[:, :, ::-1]
        out[valid] = coloured[valid]
    return out


def _instance_rgb(instance: np.ndarray) -> np.ndarray:
    palette = (np.random.default_rng(7).uniform(60, 255, (256, 3))).astype(np.uint8)
    out = np.zeros((*instance.shape, 3), np.uint8)
    fg = instance >= 0
    out[fg] = palette[instance[fg] % 256]
    return out


def _gray_rgb(img: np.ndarray, vmax: float) -> np.ndarray:
    g = (np.clip(img / vmax, 0, 1) * 255).astype(np.uint8)
    return np.repeat(g[..., None], 3, axis=-1)


def contact_sheet(views: Sequence[ViewBuffers], max_views: int = 4) -> np.ndarray:
    """An RGB uint8 image: one row per view (at most ``max_views``), 4 columns; rows of views of other sizes (the
    sensors of a multi-sensor set) are padded with black on the right to the widest."""
    rows = []
    for v in list(views)[:max_views]:
        rgb = v.rgb if v.rgb is not None else np.zeros((*v.depth.shape, 3), np.uint8)
        cells = [rgb, _depth_rgb(v.depth), _instance_rgb(v.instance), _gray_rgb(v.curvature, CURVATURE_DISPLAY_MAX)]
        rows.append(np.concatenate([np.pad(c, ((2, 2), (2, 2), (0, 0))) for c in cells], axis=1))
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in rows]
    return np.concatenate(rows, axis=0)


def write_contact_sheet(path: str | Path, views: Sequence[ViewBuffers], max_views: int = 4) -> None:
    """Write :func:`contact_sheet` as a PNG (atomically)."""
    write_image(path, contact_sheet(views, max_views))
