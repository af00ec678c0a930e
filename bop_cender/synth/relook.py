"""A copy of a dataset whose images of one split are drawn again in another look (same scenes, same poses).

Why: the robustness benchmark (``scripts/robustness.py``) scores the same test scenes in several looks; every look
(the foreign camera here, pyrender's ``scripts/rerender_pyrender.py``) is a copy read by the same loader, unchanged,
with every other file (GT, cameras, models, masks) as it was. The copy is built in ``DST.partial`` and renamed to ``DST`` once every image is written, so an interrupted run leaves
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
from bop_cender.data.types import CameraView, Dataset, Scene
from bop_cender.synth.sensor_look import SensorLook, apply_sensor_look, look_rng

#: ``(scene, view, name) -> image``: the view's new uint8 ``(H, W, 3)`` or ``(H, W)`` image; ``name`` is its path
#: relative to the dataset root (a per-image seed).
Redraw = Callable[[Scene, CameraView, str], np.ndarray]


#: The split a re-rendered look redraws when none is named: DIMO's synthetic camera, T-LESS's test images.
DEFAULT_SPLIT = {"dimo": "sim", "tless": "test"}


def add_look_arguments(parser) -> None:
    """The arguments every re-rendering script takes (``scripts/rerender_*.py``): ``src``, ``dst``, ``--dataset``,
    ``--split``, ``--limit-scenes``; each script adds its own."""
    from pathlib import Path as _Path

    parser.add_argument("src", type=_Path, help="a DIMO- or T-LESS-layout dataset root")
    parser.add_argument("dst", type=_Path, help="where the copy goes (must not exist)")
    parser.add_argument(
        "--dataset", choices=tuple(DEFAULT_SPLIT), default="dimo", help="the layout of SRC (default dimo)"
    )
    parser.add_argument(
        "--split", default=None, help="the split whose images are rendered again (default: dimo sim, tless test)"
    )
    parser.add_argument("--limit-scenes", type=int, default=None, help="only the first K scenes of the split")


def open_every_image(layout: str, root: Path, split: str) -> Dataset:
    """The split with every image a view of some scene (DIMO: every variant and viewpoint, not only the paper's
    selection; T-LESS / BOP: each image its own group), so that no image of the copy keeps the source's look."""
    if layout == "dimo":
        return open_dimo(root, split, DimoSelection.everything())
    return open_dataset(DatasetRequest(layout, root, split, n_views=1))


def relook_split(
    dataset: Dataset,
    src: Path,
    dst: Path,
    redraw: Redraw,
    limit_scenes: int | None = None,
    progress: Callable[[str], None] = lambda _line: None,
) -> int:
    """Copy ``src`` to ``dst`` with every colour image of ``dataset`` (a split of ``src``, opened by
    :func:`open_every_image`) redrawn; returns the number of images redrawn.

    Raises:
        FileExistsError: ``dst`` exists.
        Whatever ``redraw`` raises, with nothing left behind.
    """
    if dst.exists():
        raise FileExistsError(f"{dst} exists; give a new folder")
    partial = dst.with_name(dst.name + ".partial")
    if partial.exists():
        shutil.rmtree(partial)
    shutil.copytree(src, partial)
    done: set[Path] = set()
    try:
        keys = dataset.scene_keys[:limit_scenes]
        for n, key in enumerate(keys, 1):
            scene = dataset.scene(key)
            for view in scene.views:
                if view.rgb_path is None or Path(view.rgb_path) in done:
                    continue
                name = Path(view.rgb_path).relative_to(src).as_posix()
                Image.fromarray(redraw(scene, view, name)).save(partial / name)
                done.add(Path(view.rgb_path))
            progress(f"relook: {n}/{len(keys)} scene {key}")
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)  # nothing half-written is left
        raise
    partial.rename(dst)
    return len(done)


def sensor_redraw(seed: int) -> Redraw:
    """The foreign camera of :mod:`bop_cender.synth.sensor_look`, drawn per image from ``seed`` and its name."""

    def redraw(scene: Scene, view: CameraView, name: str) -> np.ndarray:
        with Image.open(view.rgb_path) as source:
            image = np.asarray(source.convert("L" if source.mode in ("L", "I;16", "I") else "RGB"))
        rng = look_rng(seed, name)
        return apply_sensor_look(image, SensorLook.draw(rng), rng)

    return redraw
