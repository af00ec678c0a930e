"""Mostly-zero heatmaps kept as patches: the center targets of a training set without their empty pixels.

A T-LESS-layout center target has one channel per object id (30) and a few blobs per view, so nearly all
of its ``30 x 540 x 720`` bytes are zero: 768 dense views take 9 GB, more than the images. Each non-empty
``(view, channel)`` is kept as the bounding box of its non-zero pixels instead (tens of kB), and batches
are made dense again on demand, bit for bit the same bytes as the dense maps.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


class PatchMaps:
    """``(N, C, H, W)`` uint8 maps as one bounding-box patch per non-empty ``(sample, channel)``.

    Attributes:
        shape: ``(N, C, H, W)`` of the dense maps.
        boxes: ``(P, 6)`` int64 ``sample, channel, y0, x0, h, w`` of each patch, sorted by sample.
        starts: ``(P + 1,)`` offset of each patch's bytes in ``data`` (row-major ``h x w``).
        data: the patches' bytes, concatenated.
    """

    def __init__(self, shape: tuple[int, int, int, int], boxes: np.ndarray, data: np.ndarray) -> None:
        self.shape = tuple(int(s) for s in shape)
        self.boxes = np.asarray(boxes, np.int64).reshape(-1, 6)
        self.data = np.asarray(data).ravel()
        if self.data.dtype != np.uint8:
            raise ValueError(f"patch bytes must be uint8, got {self.data.dtype}")
        N, C, H, W = self.shape
        n, c, y0, x0, h, w = self.boxes.T
        inside = (n >= 0) & (n < N) & (c >= 0) & (c < C) & (y0 >= 0) & (x0 >= 0) & (h > 0) & (w > 0)
        if not bool(np.all(inside & (y0 + h <= H) & (x0 + w <= W))) or bool(np.any(np.diff(n) < 0)):
            raise ValueError(f"patch boxes must lie inside {self.shape} and be sorted by sample")
        self.starts = np.concatenate([[0], np.cumsum(h * w)])
        if self.starts[-1] != self.data.size:
            raise ValueError(f"{self.data.size} bytes for patches of {self.starts[-1]}")
        self._first = np.searchsorted(self.boxes[:, 0], np.arange(self.shape[0] + 1))

    @staticmethod
    def from_dense(maps: Sequence[np.ndarray] | np.ndarray) -> PatchMaps:
        """Patches of ``maps``: ``(C, H, W)`` uint8 arrays of one size, one per sample (or one ``(N, C, H, W)``
        array, which may hold no sample)."""
        boxes, chunks = [], []
        shape: tuple[int, ...] | None = maps.shape[1:] if isinstance(maps, np.ndarray) else None
        for n, m in enumerate(maps):
            if m.dtype != np.uint8:
                raise ValueError(f"map {n} is {m.dtype}, not uint8")
            if shape is None:
                shape = m.shape
            elif m.shape != shape:
                raise ValueError(f"map {n} is {m.shape}, the first {shape}")
            rows, cols = m.any(axis=2), m.any(axis=1)  # (C, H), (C, W)
            for c in np.flatnonzero(rows.any(axis=1)):
                ys, xs = np.flatnonzero(rows[c]), np.flatnonzero(cols[c])
                y0, y1, x0, x1 = ys[0], ys[-1] + 1, xs[0], xs[-1] + 1
                boxes.append((n, c, y0, x0, y1 - y0, x1 - x0))
                chunks.append(m[c, y0:y1, x0:x1].ravel())
        if shape is None:
            raise ValueError("no maps")
        data = np.concatenate(chunks) if chunks else np.zeros(0, np.uint8)
        return PatchMaps((len(maps), *shape), np.array(boxes, np.int64).reshape(-1, 6), data)

    @staticmethod
    def concat(parts: Sequence[PatchMaps]) -> PatchMaps:
        """The samples of ``parts`` (maps of one ``(C, H, W)``), in order."""
        if not parts:
            raise ValueError("no maps")
        if len({p.shape[1:] for p in parts}) > 1:
            raise ValueError(f"maps of different sizes: {sorted({p.shape[1:] for p in parts})}")
        offsets = np.cumsum([0] + [len(p) for p in parts[:-1]])
        boxes = np.concatenate([p.boxes + np.array([o, 0, 0, 0, 0, 0]) for p, o in zip(parts, offsets, strict=True)])
        data = np.concatenate([p.data for p in parts])
        return PatchMaps((sum(len(p) for p in parts), *parts[0].shape[1:]), boxes, data)

    def __len__(self) -> int:
        return self.shape[0]

    @property
    def nbytes(self) -> int:
        return int(self.data.nbytes + self.boxes.nbytes)

    def dense(self, indices: Sequence[int] | np.ndarray) -> np.ndarray:
        """The dense maps of samples ``indices``: ``(B, C, H, W)`` uint8."""
        idx = np.asarray(indices, np.int64).ravel()
        out = np.zeros((idx.size, *self.shape[1:]), np.uint8)
        for b, n in enumerate(idx):
            if not 0 <= n < self.shape[0]:
                raise IndexError(f"sample {n} of {self.shape[0]}")
            for p in range(self._first[n], self._first[n + 1]):
                _, c, y0, x0, h, w = self.boxes[p]
                out[b, c, y0 : y0 + h, x0 : x0 + w] = self.data[self.starts[p] : self.starts[p + 1]].reshape(h, w)
        return out
