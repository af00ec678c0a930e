"""Readers for the four JSON files of one DIMO scene folder, each validating what it reads.

DIMO is the BOP layout with two extra files (``scene_gt_world.json``: one model-to-world pose per
object instance; ``scene_info.json``: light / carrier / parts / viewpoint per image) and one
deviation: ``scene_camera.json`` stores camera-to-world poses (``cam_R_c2w``, ``cam_t_c2w``).
Every reader turns one file into typed arrays (mm, float64) and raises a :class:`DatasetError`
that names the file, the key (``3.cam_R_c2w`` = image 3's key; ``3[1].obj_id`` = image 3's
second entry; ``[1].cam_t_m2w`` = the list's second entry) and what was expected.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bop_cender.data.bop_io import as_int, load_image_dict, load_json, require_keys
from bop_cender.data.consistency import ResidualTracker
from bop_cender.data.layout import SCENE_CAMERA, SCENE_GT
from bop_cender.data.types import check_intrinsics, check_matrix, check_pose
from bop_cender.errors import DatasetError
from bop_cender.geometry.poses import c2w_to_w2c, make_pose

CAMERA_FILE = SCENE_CAMERA
GT_FILE = SCENE_GT
GT_WORLD_FILE = "scene_gt_world.json"
INFO_FILE = "scene_info.json"

#: ``scene_info.json`` keys: (newer name, used in memory; older name, Oct 2021 README).
INFO_KEYS: tuple[tuple[str, str], ...] = (
    ("light", "light_id"),
    ("carrier", "carrier_id"),
    ("parts", "composition_type"),
    ("viewpoint", "viewpoint_id"),
)
#: Keys the selection needs; ``light`` is kept when present but not required.
REQUIRED_INFO = ("carrier", "parts", "viewpoint")


@dataclass(frozen=True, eq=False)
class DimoCamera:
    """One image's calibration: ``K (3, 3)`` and ``T_cam_world (4, 4)`` (already world-to-camera)."""

    K: np.ndarray
    T_cam_world: np.ndarray


@dataclass(frozen=True, eq=False)
class WorldObject:
    """One entry of ``scene_gt_world.json``: an object instance and its ``T_world_model (4, 4)``."""

    obj_id: int
    T_world_model: np.ndarray


def dimo_image_dir(scene_dir: str | Path) -> Path:
    """The colour image folder of a DIMO scene (the official loader hard-codes ``rgb/``)."""
    return Path(scene_dir) / "rgb"


def rgb_path(scene_dir: str | Path, im_id: int) -> Path:
    """``<scene_dir>/rgb/{im_id:06d}.png``."""
    return dimo_image_dir(scene_dir) / f"{im_id:06d}.png"


def read_scene_info(path: Path) -> dict[int, dict[str, Any]]:
    """``scene_info.json`` per image, normalised to the newer key names with int values.

    Both spellings are accepted (``carrier`` / ``carrier_id``, ``parts`` / ``composition_type``,
    ``viewpoint`` / ``viewpoint_id``, ``light`` / ``light_id``), values int or numeric strings.
    Other keys are kept as they are.
    """
    return {im_id: _normalise_info(entry, path, im_id) for im_id, entry in load_image_dict(path).items()}


def _normalise_info(entry: Any, path: Path, im_id: int) -> dict[str, Any]:
    if not isinstance(entry, Mapping):
        raise DatasetError(f"expected an object, got {type(entry).__name__}", file=path, field=str(im_id))
    spelled = {name for pair in INFO_KEYS for name in pair}
    out: dict[str, Any] = {k: v for k, v in entry.items() if k not in spelled}
    for new, old in INFO_KEYS:
        values = [(key, as_int(entry[key], path, f"{im_id}.{key}", strings=True)) for key in (new, old) if key in entry]
        if not values:
            if new in REQUIRED_INFO:
                raise DatasetError(f"missing key '{new}' (or older '{old}')", file=path, field=f"{im_id}.{new}")
            continue
        if len(values) == 2 and values[0][1] != values[1][1]:
            raise DatasetError(
                f"'{old}' = {values[1][1]} disagrees with '{new}' = {values[0][1]}", file=path, field=f"{im_id}.{old}"
            )
        out[new] = values[0][1]
    return out


def read_cameras(path: Path, tracker: ResidualTracker) -> dict[int, DimoCamera]:
    """``scene_camera.json``: intrinsics and world-to-camera poses per image.

    DIMO stores camera-to-world (``cam_R_c2w``/``cam_t_c2w``): it is preferred and inverted here,
    once. BOP's ``cam_R_w2c``/``cam_t_w2c`` is accepted alone; when both are present they must
    agree (checked with ``tracker``: fails beyond 5 mm / 0.01 rad).
    """
    cameras: dict[int, DimoCamera] = {}
    for im_id, entry in load_image_dict(path).items():
        where = str(im_id)
        require_keys(entry, ("cam_K",), path, where)
        K_flat = check_matrix(entry["cam_K"], (9,), f"{where}.cam_K", str(path))
        K = check_intrinsics(K_flat.reshape(3, 3), f"{where}.cam_K", str(path))
        T_world_cam = read_pose(entry, "cam_R_c2w", "cam_t_c2w", path, where)
        T_cam_world_stored = read_pose(entry, "cam_R_w2c", "cam_t_w2c", path, where)
        if T_world_cam is None and T_cam_world_stored is None:
            raise DatasetError(
                "missing camera pose: expected cam_R_c2w/cam_t_c2w (DIMO) or cam_R_w2c/cam_t_w2c (BOP)",
                file=path,
                field=where,
            )
        if T_world_cam is not None:
            T_cam_world = c2w_to_w2c(T_world_cam)
            if T_cam_world_stored is not None:
                relation = "the inverse of cam_R_c2w/cam_t_c2w"
                tracker.check(T_cam_world, T_cam_world_stored, path, f"{where}.cam_R_w2c/cam_t_w2c", relation)
        else:
            T_cam_world = T_cam_world_stored
        cameras[im_id] = DimoCamera(K=K, T_cam_world=T_cam_world)
    return cameras


def read_gt_world(path: Path, known_obj_ids: Iterable[int]) -> list[WorldObject]:
    """``scene_gt_world.json``: a list, one ``{obj_id, cam_R_m2w, cam_t_m2w}`` per object instance.

    Every ``obj_id`` must be in ``models_info.json`` (``known_obj_ids``), carriers included.
    """
    data = load_json(path)
    if not isinstance(data, list):
        raise DatasetError(f"expected a list with one entry per object instance, got {type(data).__name__}", file=path)
    known = set(known_obj_ids)
    objects = []
    for k, entry in enumerate(data):
        where = f"[{k}]"
        require_keys(entry, ("obj_id", "cam_R_m2w", "cam_t_m2w"), path, where)
        obj_id = _obj_id(entry["obj_id"], path, f"{where}.obj_id")
        if obj_id not in known:
            raise DatasetError(
                f"object {obj_id} is not in models/models_info.json (known: {', '.join(map(str, sorted(known)))})",
                file=path,
                field=f"{where}.obj_id",
            )
        objects.append(WorldObject(obj_id, read_pose(entry, "cam_R_m2w", "cam_t_m2w", path, where)))
    return objects


def check_scene_gt(
    path: Path,
    scene_gt: Mapping[int, Any],
    world: list[WorldObject],
    cameras: Mapping[int, DimoCamera],
    tracker: ResidualTracker,
) -> dict[int, list[np.ndarray]]:
    """Check every image's ``scene_gt`` list against ``scene_gt_world.json`` and the cameras.

    As the official loader assumes, each image lists every instance of ``world``, in the same
    order, with the same int ``obj_id``; and ``T_cam_model == T_cam_world @ T_world_model`` (checked
    with ``tracker``: a frame mix-up is off by hundreds of mm and fails).

    Args:
        scene_gt: ``scene_gt.json`` as loaded by :func:`~bop_cender.data.bop_io.load_image_dict`; its image ids must
            already be known to equal those of ``cameras``.

    Returns:
        Per image id, the stored ``T_cam_model (4, 4)`` of each entry (float64 as read), in ``world`` order.
    """
    poses: dict[int, list[np.ndarray]] = {}
    relation = f"{CAMERA_FILE} and {GT_WORLD_FILE} (T_cam_world @ T_world_model)"
    for im_id, entries in scene_gt.items():
        if not isinstance(entries, list):
            raise DatasetError(f"expected a list of objects, got {type(entries).__name__}", file=path, field=str(im_id))
        if len(entries) != len(world):
            raise DatasetError(
                f"expected {len(world)} entries (one per {GT_WORLD_FILE} entry, same order), got {len(entries)}",
                file=path,
                field=str(im_id),
            )
        T_cam_world = cameras[im_id].T_cam_world
        for k, (entry, obj) in enumerate(zip(entries, world, strict=True)):
            where = f"{im_id}[{k}]"
            require_keys(entry, ("obj_id", "cam_R_m2c", "cam_t_m2c"), path, where)
            obj_id = _obj_id(entry["obj_id"], path, f"{where}.obj_id")
            if obj_id != obj.obj_id:
                raise DatasetError(
                    f"expected obj_id {obj.obj_id} ({GT_WORLD_FILE} entry {k}; every image lists the scene's objects"
                    f" in the same order), got {obj_id}",
                    file=path,
                    field=f"{where}.obj_id",
                )
            T_cam_model = read_pose(entry, "cam_R_m2c", "cam_t_m2c", path, where)
            tracker.check(T_cam_world @ obj.T_world_model, T_cam_model, path, where, relation)
            poses.setdefault(im_id, []).append(T_cam_model)
    return poses


def read_pose(entry: Mapping, r_key: str, t_key: str, path: Path, where: str) -> np.ndarray | None:
    """The rigid ``(4, 4)`` transform stored as ``entry[r_key]`` (9, row-major) and ``entry[t_key]`` (3, mm).

    Returns None when neither key is present; raises when only one is, or when the values are
    malformed (wrong length, NaN, a rotation that is not orthonormal).
    """
    has_r, has_t = r_key in entry, t_key in entry
    if not has_r and not has_t:
        return None
    if has_r != has_t:
        present, absent = (r_key, t_key) if has_r else (t_key, r_key)
        raise DatasetError(f"missing key (given '{present}' without it)", file=path, field=f"{where}.{absent}")
    source = str(path)
    R = check_matrix(entry[r_key], (9,), f"{where}.{r_key}", source).reshape(3, 3)
    t = check_matrix(entry[t_key], (3,), f"{where}.{t_key}", source)
    return check_pose(make_pose(R, t), f"{where}.{r_key}", source)


def _obj_id(value: Any, path: Path, where: str) -> int:
    """Object ids are JSON ints (the official loader compares them with ``==``, so "3" != 3)."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise DatasetError(f"expected an integer object id, got {value!r}", file=path, field=where)
    return value
