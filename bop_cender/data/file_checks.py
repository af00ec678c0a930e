"""Check the files ``run`` and ``score`` will read: every model mesh and every colour and depth image.

Opening a split reads its JSON files and checks them, but not the meshes nor the images, which are read
late (a mesh when the first estimate of its object is scored, an image when its scene is run): a broken
file fails minutes into a run, or never, where a decoder returns a half image. ``bop-cender info`` runs
:func:`check_files` so that every such problem is listed at once, before anything else runs.

Meshes are read by the readers ``run`` and ``score`` use (:func:`bop_cender.data.ply_ascii.ascii_mesh`,
else :func:`bop_cender.data.bop_io.load_ply`), so they pass or fail exactly as there
(:func:`~bop_cender.data.ply_ascii.check_mesh`). Images are checked from their headers by default
(:mod:`bop_cender.data.image_header`: size against the split's, a depth image 16-bit and single-channel)
or, with ``deep``, decoded in full by the loaders' readers (:func:`~bop_cender.data.bop_io.load_rgb`,
:func:`~bop_cender.data.bop_io.load_depth`), which also catches pixels damaged behind a good header. Masks
are not checked: neither ``run`` nor ``score`` reads them.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from bop_cender.data.bop_io import image_shape
from bop_cender.data.types import Dataset, ObjectModel, Scene
from bop_cender.errors import DatasetError
from bop_cender.progress import progress_bar

#: Channels an intensity image may have, per modality (as decoded unchanged; 4: colour with alpha).
MODALITY_CHANNELS = {"gray": (1,), "rgb": (3, 4)}


@dataclass(frozen=True)
class ImageFile:
    """One image to check: its path, the size it must have, and whether it is a depth image (``modality``: ``gray``
    or ``rgb`` where the layout says, as the multi-sensor one does: then its channels are checked too)."""

    path: Path
    size: tuple[int, int]
    depth: bool = False
    depth_scale: float | None = None
    modality: str | None = None


@dataclass
class FileCheck:
    """What :func:`check_files` checked and every problem it found (one formatted line each)."""

    deep: bool
    meshes: int = 0
    images: int = 0
    problems: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def summary(self) -> str:
        """``checked 42 meshes, 840 images (headers): no problem found`` (or ``: 3 problems``)."""
        how = "decoded" if self.deep else "headers"
        n = len(self.problems)
        found = "no problem found" if not n else f"{n} problem{'s' * (n != 1)}"
        return f"checked {self.meshes} meshes, {self.images} images ({how}): {found}"


def check_meshes(models: Iterable[ObjectModel]) -> tuple[int, list[str]]:
    """``(meshes checked, problems)`` for the PLY files of ``models`` (each file once): readable, and the size their
    ``models_info.json`` entry says (:func:`~bop_cender.data.models.check_extent`)."""
    from bop_cender.data.bop_io import load_ply
    from bop_cender.data.models import check_extent
    from bop_cender.data.ply_ascii import ascii_mesh

    by_path = {Path(m.path): m for m in models}
    paths = sorted(by_path)
    problems = []
    for path in paths:
        try:
            mesh = ascii_mesh(path)
            check_extent(by_path[path], mesh.vertices if mesh is not None else load_ply(path).vertices)
        except DatasetError as e:
            problems.append(e.format())
        except OSError as e:
            problems.append(DatasetError(f"cannot read: {e.strerror}", file=path).format())
    return len(paths), problems


def unlisted_meshes(models: Iterable[ObjectModel]) -> list[str]:
    """One line per ``obj_NNNNNN.ply`` in a models folder without an entry in its ``models_info.json``: the
    loaders read the listed models only, so such a mesh is neither scored nor rendered as an occluder (a
    model left out of the info file by mistake would be unknown to ``run`` and ``score`` alike)."""
    listed: dict[Path, set[int]] = {}
    for model in models:
        listed.setdefault(Path(model.path).parent, set()).add(model.obj_id)
    lines = []
    for folder, ids in sorted(listed.items()):
        for path in sorted(folder.glob("obj_*.ply")):
            digits = path.stem.removeprefix("obj_")
            if digits.isdigit() and int(digits) not in ids:
                lines.append(f"{path}: no entry {int(digits)} in models_info.json: not loaded (neither scored nor"
                             " an occluder)")  # fmt: skip
    return lines


def scene_images(scene: Scene, split_size: tuple[int, int] | None) -> list[ImageFile]:
    """The colour and depth images of ``scene``'s views, each with the size it must have: the split's
    (DIMO reads each view's size from its own image, so only the split's size can disagree), else the view's;
    a multi-sensor view's, its sensor's."""
    out = []
    for view in scene.views:
        size = (view.width, view.height) if view.sensor is not None or split_size is None else split_size
        if view.rgb_path is not None:
            out.append(
                ImageFile(Path(view.rgb_path), size, modality=view.info.get("modality") if view.sensor else None)
            )
        if view.depth_path is not None:
            out.append(ImageFile(Path(view.depth_path), size, depth=True, depth_scale=view.depth_scale))
    return out


def check_image(image: ImageFile, deep: bool) -> str | None:
    """The problem of one image, formatted (``FILE: field: message``), or None."""
    try:
        width, height = _decoded_size(image) if deep else _header_size(image)
    except DatasetError as e:
        return e.format()
    if (width, height) != tuple(image.size):
        expected = f"{image.size[0]}x{image.size[1]}"
        whose = "the split's" if image.modality is None else "its sensor's"
        return DatasetError(
            f"image is {width}x{height}, expected {expected} ({whose} image size)", file=image.path, field="size"
        ).format()
    if image.modality in MODALITY_CHANNELS:
        try:
            channels = image_shape(image.path)[2]
        except DatasetError as e:
            return e.format()
        if channels not in MODALITY_CHANNELS[image.modality]:
            return DatasetError(
                f"a {channels}-channel image where {image.modality} is expected"
                f" ({' or '.join(map(str, MODALITY_CHANNELS[image.modality]))} channels)",
                file=image.path,
                field="channels",
            ).format()
    return None


def _header_size(image: ImageFile) -> tuple[int, int]:
    from bop_cender.data.image_header import read_image_header

    header = read_image_header(image.path)
    if header is None:  # not a PNG or JPEG: only a decoder can tell
        return _decoded_size(image)
    if image.depth:
        if header.format != "png" or header.channels != 1:
            raise DatasetError(
                f"expected a single-channel 16-bit PNG depth image, got a {header.channels}-channel {header.format}",
                file=image.path,
                field="depth",
            )
        if header.bit_depth != 16:
            raise DatasetError(
                f"expected a 16-bit depth image, got {header.bit_depth}-bit", file=image.path, field="depth"
            )
    return header.width, header.height


def _decoded_size(image: ImageFile) -> tuple[int, int]:
    from bop_cender.data.bop_io import load_depth, load_rgb

    if image.depth:
        pixels = load_depth(image.path, image.depth_scale or 1.0)
    else:
        pixels = load_rgb(image.path)
        if image.path.suffix.lower() in (".jpg", ".jpeg"):
            _check_jpeg_end(image.path)
    return int(pixels.shape[1]), int(pixels.shape[0])


def _check_jpeg_end(path: Path) -> None:
    """A JPEG cut short still decodes (the missing rows grey, a warning on stderr): its end-of-image
    marker is missing."""
    with path.open("rb") as f:
        f.seek(max(0, path.stat().st_size - 64))
        tail = f.read().rstrip(b"\0")
    if not tail.endswith(b"\xff\xd9"):
        raise DatasetError("JPEG cut short (no end-of-image marker): the decoder fills the rest grey", file=path)


def check_images(images: list[ImageFile], deep: bool, progress: bool = True) -> list[str]:
    """The problems of ``images`` (each path once), in their order; decoded on several threads with ``deep``
    (the decoders release the GIL)."""
    unique = list({image.path: image for image in images}.values())
    threads = max(1, min(8, os.cpu_count() or 1)) if deep else 1
    bar = progress_bar(
        total=len(unique), desc="checking images", unit="image", disable=not progress or len(unique) < 200, leave=False
    )
    with bar, ThreadPoolExecutor(threads) as pool:
        problems = []
        for problem in pool.map(functools.partial(check_image, deep=deep), unique):
            bar.update()
            if problem is not None:
                problems.append(problem)
    return problems


def check_files(dataset: Dataset, scenes: Iterable[Scene], deep: bool = False, progress: bool = True) -> FileCheck:
    """Check the meshes of ``dataset`` (models and evaluation models) and the images of ``scenes``.

    Args:
        scenes: the scenes loaded (a scene that failed to load is reported by its loader, not here).
        deep: decode every image in full, not its header alone.
    """
    result = FileCheck(deep=deep)
    models = [*dataset.models.values(), *dataset.eval_models.values()]
    result.meshes, mesh_problems = check_meshes(models)
    result.notes = unlisted_meshes(models)
    scenes = list(scenes)
    images = [image for scene in scenes for image in scene_images(scene, dataset.image_size)]
    result.images = len({image.path for image in images})
    result.problems = mesh_problems + colourless_views(scenes) + check_images(images, deep, progress)
    return result


def colourless_views(scenes: Iterable[Scene]) -> list[str]:
    """One line per scene with views that have no colour image (no ``rgb/`` or ``gray/`` folder): the method runs on
    colour images, so ``run`` fails on such a scene; ``info`` checked only the depth images it found there."""
    lines = []
    for scene in scenes:
        missing = [v.im_id for v in scene.views if v.rgb_path is None]
        if missing:
            source = scene.views[0].source
            folder = Path(source).parent if source else None
            shown = ", ".join(map(str, missing[:5])) + (" ..." if len(missing) > 5 else "")
            lines.append(
                DatasetError(
                    f"scene {scene.key}: no colour image of {len(missing)} view(s) (images {shown}): no rgb/ or gray/"
                    " folder, and the method runs on colour images",
                    file=folder,
                ).format()
            )
    return lines
