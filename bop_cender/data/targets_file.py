"""BOP'19 test targets as the toolkit writes them (``test_targets_bop19.json``): one type, one reader, one writer.

The loaders read the dataset's file (:meth:`bop_cender.data.types.Dataset.bop19_targets`); evaluation and the
toolkit adapter use the values, never the file.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from bop_cender.data.bop_io import load_json, save_json
from bop_cender.errors import DatasetError

#: A BOP scene id: an int in files and results, a folder name string in memory.
SceneId = int | str


@dataclass(frozen=True)
class Target:
    """One line of ``test_targets_bop19.json``: ``inst_count`` instances of ``obj_id`` to find in an image."""

    scene_id: SceneId
    im_id: int
    obj_id: int
    inst_count: int


def read_targets(path: str | Path) -> list[Target]:
    """``test_targets_bop19.json`` as Targets (scene ids as ints); every entry needs ``inst_count`` >= 1.

    Raises:
        DatasetError: not a list of objects with integer scene_id, im_id, obj_id, inst_count.
    """
    path = Path(path)
    entries = load_json(path)
    if not isinstance(entries, list):
        raise DatasetError(f"expected a list of targets, got {type(entries).__name__}", file=path)
    targets = []
    first: dict[tuple[int, int, int], int] = {}
    for i, entry in enumerate(entries):
        values = []
        for key in ("scene_id", "im_id", "obj_id", "inst_count"):
            value = entry.get(key) if isinstance(entry, dict) else None
            if isinstance(value, bool) or not isinstance(value, int) or value < (1 if key == "inst_count" else 0):
                what = "a positive integer" if key == "inst_count" else "a non-negative integer"
                raise DatasetError(f"expected {what}, got {value!r}", file=path, field=f"[{i}].{key}")
            values.append(value)
        check_not_repeated(first, (values[0], values[1], values[2]), i, path)
        targets.append(Target(*values))
    return targets


def read_image_targets(path: str | Path) -> list[tuple[int, int]]:
    """``test_targets_bop24.json`` as ``(scene_id, im_id)`` pairs in file order, each once (the toolkit keys its
    targets by image, so a repeated image is the same target; other keys of an entry, e.g. ``obj_id``, are not
    used by the detection task).

    Raises:
        DatasetError: not a list of objects with non-negative integer scene_id and im_id.
    """
    path = Path(path)
    entries = load_json(path)
    if not isinstance(entries, list):
        raise DatasetError(f"expected a list of targets, got {type(entries).__name__}", file=path)
    images: dict[tuple[int, int], None] = {}
    for i, entry in enumerate(entries):
        values = []
        for key in ("scene_id", "im_id"):
            value = entry.get(key) if isinstance(entry, dict) else None
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise DatasetError(f"expected a non-negative integer, got {value!r}", file=path, field=f"[{i}].{key}")
            values.append(value)
        images.setdefault((values[0], values[1]), None)
    return list(images)


def image_selection(path: Path, index: Mapping[str, Iterable[int]], folder: str) -> dict[str, set[int]]:
    """The images of ``test_targets_bop24.json`` per scene folder of ``index`` (folder name -> image ids on disk).

    Raises:
        DatasetError: malformed, or an image whose scene folder or image the split does not hold (the field named).
    """
    from bop_cender.data.scene_ids import scene_folder_to_int

    folders = {scene_folder_to_int(sid): sid for sid in index}
    selected: dict[str, set[int]] = {}
    for i, (scene, im) in enumerate(read_image_targets(path)):
        if scene not in folders:
            raise DatasetError(f"scene {scene} has no folder in {folder}/", file=path, field=f"[{i}].scene_id")
        if im not in index[folders[scene]]:
            raise DatasetError(f"image {im} is not in {folder}/{folders[scene]}", file=path, field=f"[{i}].im_id")
        selected.setdefault(folders[scene], set()).add(im)
    return selected


def check_not_repeated(
    first: dict[tuple[int, int, int], int], key: tuple[int, int, int], index: int, path: Path
) -> None:
    """Refuse a second entry for one (scene, image, object): the toolkit's file has one, its ``inst_count`` the
    number of instances; of two, one ``inst_count`` would be dropped without a word. ``first`` maps the keys
    seen so far to their entry index (updated).

    Raises:
        DatasetError: ``field`` the repeated entry.
    """
    seen = first.setdefault(key, index)
    if seen != index:
        raise DatasetError(
            f"repeats the target of scene {key[0]}, image {key[1]}, object {key[2]} (first at [{seen}]): one entry per"
            " image and object, whose inst_count is its number of instances",
            file=path,
            field=f"[{index}]",
        )


def write_targets(path: str | Path, targets: Iterable[Target]) -> None:
    """Write targets as ``test_targets_bop19.json`` (the toolkit's key order and layout), atomically."""
    save_json(
        path,
        [{"im_id": t.im_id, "inst_count": t.inst_count, "obj_id": t.obj_id, "scene_id": t.scene_id} for t in targets],
    )
