"""Depth renders cut to their silhouettes: what the VSD renders hand to VSD, with no torch in sight.

Renders for VSD are cut right away to the bounding box of their silhouette inside the image: VSD only
looks at pixels where either render is non-zero, so a crop loses nothing, and thousands of renders of a
few thousand pixels each stay small in memory and cheap to send between processes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bop_cender.eval.vsd import Window


@dataclass(frozen=True)
class DepthCrops:
    """E depth renders, each cut to its silhouette's bounding box inside the image.

    Attributes:
        depth: E arrays ``(h_e, w_e)`` float32, z in mm, 0 on background; ``(0, 0)`` for a render
            with no pixel inside the image.
        origin: ``(E, 2)`` int64 full-image (row, column) of each crop's first pixel.
    """

    depth: list[np.ndarray]
    origin: np.ndarray

    def __len__(self) -> int:
        return len(self.depth)

    def window(self, e: int) -> Window | None:
        """``(y0, x0, y1, x1)`` of crop ``e`` in the full image, None if empty."""
        h, w = self.depth[e].shape
        if h == 0:
            return None
        y0, x0 = (int(v) for v in self.origin[e])
        return (y0, x0, y0 + h, x0 + w)


def union_window(*windows: Window | None) -> Window | None:
    """The smallest window holding every given window (None entries ignored); None if all are None."""
    wins = [w for w in windows if w is not None]
    if not wins:
        return None
    return (min(w[0] for w in wins), min(w[1] for w in wins), max(w[2] for w in wins), max(w[3] for w in wins))


def paste(crop: np.ndarray, where: Window | None, win: Window) -> np.ndarray:
    """``crop`` (lying at ``where`` in the image, None = empty) placed in a zero ``(h, w)`` float32 image of ``win``."""
    if where == win:
        return crop
    out = np.zeros((win[2] - win[0], win[3] - win[1]), dtype=np.float32)
    if where is not None:
        out[where[0] - win[0] : where[2] - win[0], where[1] - win[1] : where[3] - win[1]] = crop
    return out
