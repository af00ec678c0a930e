"""What a resumed ``bop-cender synth`` checks in the scene folders already done: that its options would write them.

The root's record (:mod:`bop_cender.synth.record`) fixes the seeds and the look; the options that shape each
scene folder (how many images, DIMO's carrier and composition per scene) are read back from the done folders
themselves. A resume with another ``--views`` would otherwise keep folders of 13 images beside new ones of 7, and
one with other ``--carriers`` would mix carriers in a set meant to have one. Reading the folders' own files
holds for datasets written before this check existed as well, which a new record field would not.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from bop_cender.data.layout import SCENE_CAMERA
from bop_cender.errors import ConfigError, DatasetError

SCENE_INFO = "scene_info.json"


@dataclass(frozen=True)
class FolderShape:
    """What this run's options fix about one scene folder.

    Attributes:
        images: its number of images (entries of ``scene_camera.json``).
        images_option: the ``synth`` option that sets ``images``.
        info: DIMO ``scene_info.json`` values every image carries, with the option that sets each
            (``{"carrier": (2, "--carriers")}``); empty for T-LESS.
        camera_file: the camera file whose entries are the images (a multi-sensor folder's evaluated sensor's).
    """

    images: int
    images_option: str
    info: dict[str, tuple[int, str]] = field(default_factory=dict)
    camera_file: str = SCENE_CAMERA


def check_done_folder(folder: Path, shape: FolderShape) -> None:
    """Refuse to resume into a dataset whose done ``folder`` this run would have written otherwise.

    Raises:
        ConfigError: the folder has another number of images or another DIMO carrier / composition
            (``file``: the folder's file that says so, ``field``: the option).
        DatasetError: its ``scene_camera.json`` / ``scene_info.json`` cannot be read.
    """
    cameras = _load_object(folder / shape.camera_file)
    if len(cameras) != shape.images:
        _mismatch(folder / shape.camera_file, shape.images_option, f"{len(cameras)} images", f"{shape.images}")
    if not shape.info:
        return
    info = _load_object(folder / SCENE_INFO)
    for key, (wanted, option) in shape.info.items():
        found = {entry.get(key) if isinstance(entry, dict) else None for entry in info.values()}
        if found != {wanted}:
            listed = ", ".join(sorted(map(repr, found), key=str))
            _mismatch(folder / SCENE_INFO, option, f"{key} {listed}", f"{key} {wanted}")


def _load_object(path: Path) -> dict:
    try:
        content = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise DatasetError(f"cannot read a done scene folder's file to resume it: {e}", file=path) from None
    if not isinstance(content, dict) or not content:
        raise DatasetError("expected a non-empty JSON object keyed by image id", file=path)
    return content


def _mismatch(path: Path, option: str, found: str, wanted: str) -> None:
    raise ConfigError(
        f"this done scene folder has {found}, this run would write {wanted}: resuming would mix two datasets "
        f"(give the {option} it was made with, or another --out)",
        file=path,
        field=option,
    )
