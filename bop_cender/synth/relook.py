"""A copy of a dataset whose images of one split are drawn again in another look (same scenes, same poses).

Why: the robustness benchmark (``scripts/robustness.py``) scores the same test scenes in several looks; every look
is a copy read by the same loader, unchanged, with every other file (GT, cameras, models, masks) as it was. The
copy is built in ``DST.partial`` and renamed to ``DST`` once every image is written, so an interrupted run leaves
no folder that reads as complete.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
from PIL import Image

from bop_cender.data.dimo import DimoSelection, open_dimo
from bop_cender.data.registry import DatasetRequest, open_dataset
from bop_cender.data.types import Dataset
from bop_cender.synth.sensor_look import SensorLook, apply_sensor_look, look_rng

#: ``(image, name) -> image``: a uint8 ``(H, W, 3)`` or ``(H, W)`` image and its path relative to the dataset root.
Redraw = Callable[[np.ndarray, str], np.ndarray]


#: The split a re-rendered look redraws when none is named: DIMO's synthetic camera, T-LESS's test images.
DEFAULT_SPLIT = {"dimo": "sim", "tless": "test"}


def open_every_image(layout: str, root: Path, split: str) -> Dataset:
    """The split with every image a view of some scene (DIMO: every variant and viewpoint, not only the paper's
    selection; T-LESS / BOP: each image its own group), so that no image of the copy keeps the source's look."""
    if layout == "dimo":
        return open_dimo(root, split, DimoSelection.everything())
    return open_dataset(DatasetRequest(layout, root, split, n_views=1))


def relook_split(
    layout: str,
    src: Path,
    dst: Path,
    split: str,
    redraw: Redraw,
    limit_scenes: int | None = None,
    progress: Callable[[str], None] = lambda _line: None,
) -> int:
    """Copy ``src`` to ``dst`` with every colour image of ``split`` redrawn; returns the number of images redrawn.

    Raises:
        FileExistsError: ``dst`` exists.
        BopCenderError: the loader refuses ``src``.
    """
    if dst.exists():
        raise FileExistsError(f"{dst} exists; give a new folder")
    dataset = open_every_image(layout, src, split)
    partial = dst.with_name(dst.name + ".partial")
    if partial.exists():
        shutil.rmtree(partial)
    shutil.copytree(src, partial)
    done: set[Path] = set()
    try:
        keys = dataset.scene_keys[:limit_scenes]
        for n, key in enumerate(keys, 1):
            for view in dataset.scene(key).views:
                if view.rgb_path is None or Path(view.rgb_path) in done:
                    continue
                name = Path(view.rgb_path).relative_to(src).as_posix()
                with Image.open(view.rgb_path) as source:
                    mode = "L" if source.mode in ("L", "I;16", "I") else "RGB"
                    image = np.asarray(source.convert(mode))
                Image.fromarray(redraw(image, name)).save(partial / name)
                done.add(Path(view.rgb_path))
            progress(f"relook: {n}/{len(keys)} scene {key}")
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)  # nothing half-written is left
        raise
    partial.rename(dst)
    return len(done)


def sensor_redraw(seed: int) -> Redraw:
    """The foreign camera of :mod:`bop_cender.synth.sensor_look`, drawn per image from ``seed`` and its name."""

    def redraw(image: np.ndarray, name: str) -> np.ndarray:
        rng = look_rng(seed, name)
        return apply_sensor_look(image, SensorLook.draw(rng), rng)

    return redraw
