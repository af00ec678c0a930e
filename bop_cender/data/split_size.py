"""The image size of a split, voted by a few of its images rather than taken from the first one.

A split's images share one size, which the loaders need before any scene is read (the renderer's
buffers, the camera file's check, ``info``'s per-image check). Reading it from the split's first image
alone made one wrong-sized image the reference: ``info`` and ``score`` then blamed every other image of
the split and never the odd one. Here a handful of images (the first two views of the first three
scenes, colour and depth) are read from their headers and the size most of them share wins; a declared
size (the camera file) wins where any sample agrees with it, so that the odd image is the one reported.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from bop_cender.data.bop_io import image_size
from bop_cender.errors import DatasetError

SAMPLE_SCENES = 3
SAMPLE_VIEWS_PER_SCENE = 2


@dataclass(frozen=True)
class VotedSize:
    """The size most sampled images share.

    Attributes:
        size: ``(width, height)``.
        agreeing: the sampled images of that size.
        sampled: every sampled image that could be read (``agreeing`` included).
    """

    size: tuple[int, int]
    agreeing: tuple[Path, ...]
    sampled: tuple[Path, ...]


def vote_image_size(paths: Sequence[Path], declared: tuple[int, int] | None = None) -> VotedSize | None:
    """The size of ``paths``' images that the split has: ``declared`` where any image agrees with it,
    else the size most of them share (ties: the earliest image's). None where no path exists.

    Images that cannot be read are skipped (``info`` lists them one by one), unless none can be read.

    Raises:
        DatasetError: every existing path is unreadable (the first one's error).
    """
    sizes: dict[Path, tuple[int, int]] = {}
    first_error: DatasetError | None = None
    for path in paths:
        if not path.is_file():
            continue
        try:
            sizes[path] = image_size(path)
        except DatasetError as e:
            first_error = first_error or e
    if not sizes:
        if first_error is not None:
            raise first_error
        return None
    counts = Counter(sizes.values())
    if declared is not None and declared in counts:
        size = declared
    else:
        best = max(counts.values())
        size = next(s for s in sizes.values() if counts[s] == best)
    agreeing = tuple(p for p, s in sizes.items() if s == size)
    return VotedSize(size, agreeing, tuple(sizes))
