"""One BOP scene folder -> validated cameras and GT, and the lazy loader that cuts it into Scenes.

A scene folder ``{scene:06d}/`` holds ``scene_camera.json``, ``scene_gt.json``, optionally
``scene_gt_info.json``, and image folders (``rgb/`` or ``gray/``, ``depth/``, ``mask/``,
``mask_visib/``). :func:`read_scene_folder` reads and checks all of it once:

- the three JSON files have the same image-id key set; ``scene_gt_info`` lists align with ``scene_gt``;
- ``cam_K`` is 9 numbers forming a pinhole K; poses are finite with orthonormal R;
- every ``obj_id`` is a known model; ``depth_scale`` is positive;
- every image the folder's image subfolders should hold exists.

World poses of GT objects (objects are static within a test scene) are
``T_world_model = inv(T_cam_world) @ T_cam_model`` from the first image of a group where the
instance appears; every later image's ``T_cam_model`` is checked against
``T_cam_world @ T_world_model`` with a :class:`ResidualTracker` (T-LESS files are rounded, so
small residuals only warn; a frame mix-up fails).
"""

from __future__ import annotations

import os
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from bop_cender.data.bop_io import (
    as_int,
    as_number,
    check_same_image_ids,
    few_ids,
    load_image_dict,
    require_keys,
)
from bop_cender.data.consistency import FAIL_MM, ResidualTracker
from bop_cender.data.layout import SCENE_CAMERA, SCENE_GT, SCENE_GT_INFO
from bop_cender.data.types import CameraView, GtObject, Scene, check_intrinsics, check_matrix, check_pose
from bop_cender.errors import DatasetError
from bop_cender.geometry.poses import invert_pose, pose_from_bop

#: Colour (or grey) image folders, in order of preference, and the image suffixes looked for.
RGB_FOLDERS = ("rgb", "gray")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif")
#: scene_camera keys this loader interprets; any other key goes to ``CameraView.info``.
CAMERA_KEYS = frozenset({"cam_K", "cam_R_w2c", "cam_t_w2c", "depth_scale"})
#: How many parsed scene folders a loader keeps (consecutive keys come from the same folder).
FOLDER_CACHE_SIZE = 2


@dataclass(frozen=True)
class ImageCamera:
    """One ``scene_camera.json`` entry, validated.

    Attributes:
        K: ``(3, 3)`` intrinsics.
        T_cam_world: ``(4, 4)`` world-to-camera (mm), None when the entry has no ``cam_R_w2c``.
        depth_scale: mm per depth unit, None when unknown.
        info: the entry's other keys (``elev``, ``mode``, ``view_level``, ...).
    """

    K: np.ndarray
    T_cam_world: np.ndarray | None
    depth_scale: float | None
    info: dict[str, Any]


@dataclass(frozen=True)
class GtEntry:
    """One ``scene_gt.json`` annotation: ``obj_id`` and ``T_cam_model (4, 4)`` (mm)."""

    obj_id: int
    T_cam_model: np.ndarray


@dataclass(frozen=True)
class SceneFolder:
    """A scene folder's validated contents.

    Attributes:
        path: the folder.
        cameras: per image id, its camera.
        gt: per image id, its annotations in file order (list index = gt_id).
        visib: per image id, ``visib_fract`` per gt_id; None without ``scene_gt_info.json``.
        listing: per image subfolder present (``rgb``, ``depth``, ``mask``, ...), its file names.
    """

    path: Path
    cameras: dict[int, ImageCamera]
    gt: dict[int, list[GtEntry]]
    visib: dict[int, list[float]] | None
    listing: dict[str, frozenset[str]]


@dataclass(frozen=True)
class ScenePlan:
    """Which images of which scene folder one Scene holds (decided at open time)."""

    scene_id: str
    key_suffix: str
    im_ids: tuple[int, ...]
    multi_view: bool


def read_scene_folder(
    scene_dir: Path, obj_ids: Collection[int], default_depth_scale: float | None = None
) -> SceneFolder:
    """Read and check one scene folder (see the module docstring for the checks).

    Args:
        scene_dir: the ``{scene:06d}/`` folder.
        obj_ids: known object ids (the models).
        default_depth_scale: for entries without ``depth_scale`` (from the root camera file).
    """
    cam_path, gt_path, info_path = scene_dir / SCENE_CAMERA, scene_dir / SCENE_GT, scene_dir / SCENE_GT_INFO
    cam_raw = load_image_dict(cam_path)
    gt_raw = load_image_dict(gt_path)
    check_same_image_ids({cam_path: cam_raw, gt_path: gt_raw})
    cameras = {im: parse_camera(cam_raw[im], im, cam_path, default_depth_scale) for im in sorted(cam_raw)}
    gt = {im: parse_gt(gt_raw[im], im, gt_path, obj_ids) for im in sorted(gt_raw)}
    visib = None
    if info_path.is_file():
        info_raw = load_image_dict(info_path)
        check_same_image_ids({cam_path: cam_raw, info_path: info_raw})
        visib = {im: parse_visib(info_raw[im], len(gt[im]), im, info_path) for im in sorted(info_raw)}
    listing = {
        sub: frozenset(os.listdir(scene_dir / sub))
        for sub in (*RGB_FOLDERS, "depth", "mask", "mask_visib")
        if (scene_dir / sub).is_dir()
    }
    return SceneFolder(scene_dir, cameras, gt, visib, listing)


def parse_camera(entry: Any, im: int, path: Path, default_depth_scale: float | None) -> ImageCamera:
    src = str(path)
    require_keys(entry, ("cam_K",), path, str(im))
    K = check_intrinsics(check_matrix(entry["cam_K"], (9,), f"{im}: cam_K", src).reshape(3, 3), f"{im}: cam_K", src)
    has_R, has_t = "cam_R_w2c" in entry, "cam_t_w2c" in entry
    if has_R != has_t:
        raise DatasetError("cam_R_w2c and cam_t_w2c must both be present or both absent", file=path, field=str(im))
    T = None
    if has_R:
        R = check_matrix(entry["cam_R_w2c"], (9,), f"{im}: cam_R_w2c", src)
        t = check_matrix(entry["cam_t_w2c"], (3,), f"{im}: cam_t_w2c", src)
        T = check_pose(pose_from_bop(R, t), f"{im}: cam_R_w2c/cam_t_w2c", src)
    depth_scale = default_depth_scale
    if "depth_scale" in entry:
        depth_scale = as_number(entry["depth_scale"], path, f"{im}: depth_scale")
        if depth_scale <= 0:
            raise DatasetError(
                f"expected a positive depth_scale, got {depth_scale}", file=path, field=f"{im}: depth_scale"
            )
    info = {k: v for k, v in entry.items() if k not in CAMERA_KEYS}
    return ImageCamera(K, T, depth_scale, info)


def parse_gt(entries: Any, im: int, path: Path, obj_ids: Collection[int]) -> list[GtEntry]:
    src = str(path)
    if not isinstance(entries, list):
        raise DatasetError(f"expected a list of annotations, got {type(entries).__name__}", file=path, field=str(im))
    out = []
    for gt_id, e in enumerate(entries):
        where = f"{im}[{gt_id}]"
        require_keys(e, ("obj_id", "cam_R_m2c", "cam_t_m2c"), path, where)
        obj_id = as_int(e["obj_id"], path, f"{where}.obj_id")
        if obj_id not in obj_ids:
            raise DatasetError(
                f"unknown object {obj_id}; expected one of the models ({few_ids(sorted(obj_ids))})",
                file=path,
                field=f"{where}.obj_id",
            )
        R = check_matrix(e["cam_R_m2c"], (9,), f"{where}.cam_R_m2c", src)
        t = check_matrix(e["cam_t_m2c"], (3,), f"{where}.cam_t_m2c", src)
        out.append(GtEntry(obj_id, check_pose(pose_from_bop(R, t), f"{where}: cam_R_m2c/cam_t_m2c", src)))
    return out


def parse_visib(entries: Any, n_gt: int, im: int, path: Path) -> list[float]:
    if not isinstance(entries, list) or len(entries) != n_gt:
        got = len(entries) if isinstance(entries, list) else type(entries).__name__
        raise DatasetError(
            f"expected a list of {n_gt} entries (one per annotation of {SCENE_GT}), got {got}", file=path, field=str(im)
        )
    out = []
    for gt_id, e in enumerate(entries):
        where = f"{im}[{gt_id}].visib_fract"
        require_keys(e, ("visib_fract",), path, f"{im}[{gt_id}]")
        v = as_number(e["visib_fract"], path, where)
        if not -1e-6 <= v <= 1 + 1e-6:
            raise DatasetError(f"expected a fraction in [0, 1], got {v}", file=path, field=where)
        out.append(v)
    return out


@dataclass
class BopSceneLoader:
    """The lazy ``Dataset.loader``: scene key -> :class:`Scene`, reading each scene folder once.

    Picklable (the folder cache is dropped), so a Dataset can be shipped to worker processes.

    Attributes:
        residuals: the Dataset's residual dict, updated in place after each load with the
            largest GT consistency residuals seen so far (``gt_max_mm``, ``gt_max_rad``, ``gt_pairs``).
    """

    dataset: str
    split: str
    split_dir: Path
    plans: dict[str, ScenePlan]
    obj_ids: frozenset[int]
    image_size: tuple[int, int]
    default_depth_scale: float | None
    residuals: dict[str, float]
    tracker: ResidualTracker = field(default_factory=ResidualTracker)
    _folders: dict[str, SceneFolder] = field(default_factory=dict, repr=False)

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_folders"] = {}
        return state

    def __call__(self, key: str) -> Scene:
        plan = self.plans[key]
        folder = self._folder(plan.scene_id)
        gone = [im for im in plan.im_ids if im not in folder.cameras]
        if gone:
            raise DatasetError(
                f"images {few_ids(gone)} were listed when the dataset was opened but are gone",
                file=folder.path / SCENE_CAMERA,
            )
        views = tuple(self._view(folder, im, plan.multi_view) for im in plan.im_ids)
        gt = associate_instances(views, folder, self.tracker)
        self.residuals.update(
            gt_max_mm=self.tracker.max_mm, gt_max_rad=self.tracker.max_rad, gt_pairs=float(self.tracker.count)
        )
        self.tracker.report(f"{self.dataset} {self.split_dir.name}: GT poses across views")
        info: dict[str, Any] = {"split_folder": self.split_dir.name}
        if not plan.multi_view and folder.cameras[plan.im_ids[0]].T_cam_world is None:
            info["world_frame"] = "camera (no cam_R_w2c/cam_t_w2c)"
        return Scene(self.dataset, self.split, plan.scene_id, views, tuple(gt), plan.key_suffix, info)

    def _folder(self, scene_id: str) -> SceneFolder:
        if scene_id not in self._folders:
            if len(self._folders) >= FOLDER_CACHE_SIZE:
                self._folders.pop(next(iter(self._folders)))
            self._folders[scene_id] = read_scene_folder(
                self.split_dir / scene_id, self.obj_ids, self.default_depth_scale
            )
        return self._folders[scene_id]

    def _view(self, folder: SceneFolder, im: int, multi_view: bool) -> CameraView:
        cam = folder.cameras[im]
        if cam.T_cam_world is None and multi_view:  # the plan was made from the same file
            raise DatasetError("missing cam_R_w2c/cam_t_w2c", file=folder.path / SCENE_CAMERA, field=str(im))
        n_gt = len(folder.gt[im])
        depth = self._file(folder, ("depth",), f"{im:06d}", (".png",))
        if depth is not None and cam.depth_scale is None:
            raise DatasetError(
                f"missing key 'depth_scale' (needed for {depth.name})", file=folder.path / SCENE_CAMERA, field=str(im)
            )
        return CameraView(
            im_id=im,
            K=cam.K,
            T_cam_world=np.eye(4) if cam.T_cam_world is None else cam.T_cam_world,
            width=self.image_size[0],
            height=self.image_size[1],
            rgb_path=self._file(folder, RGB_FOLDERS, f"{im:06d}", IMAGE_SUFFIXES),
            depth_path=depth,
            depth_scale=cam.depth_scale,
            mask_paths=self._masks(folder, "mask", im, n_gt),
            mask_visib_paths=self._masks(folder, "mask_visib", im, n_gt),
            info=cam.info,
            source=str(folder.path / SCENE_CAMERA),
        )

    @staticmethod
    def _file(folder: SceneFolder, subs: tuple[str, ...], stem: str, suffixes: tuple[str, ...]) -> Path | None:
        """The image ``stem`` in the first of ``subs`` that exists; None when none of ``subs`` exists."""
        for sub in subs:
            if sub in folder.listing:
                for ext in suffixes:
                    if stem + ext in folder.listing[sub]:
                        return folder.path / sub / (stem + ext)
                raise DatasetError(
                    f"image missing (expected {stem} with suffix {'/'.join(suffixes)})", file=folder.path / sub
                )
        return None

    @staticmethod
    def _masks(folder: SceneFolder, sub: str, im: int, n_gt: int) -> tuple[Path, ...]:
        if sub not in folder.listing:
            return ()
        names = [f"{im:06d}_{gt_id:06d}.png" for gt_id in range(n_gt)]
        for name in names:
            if name not in folder.listing[sub]:
                raise DatasetError("mask missing (expected one per scene_gt annotation)", file=folder.path / sub / name)
        return tuple(folder.path / sub / n for n in names)


@dataclass
class _Instance:
    obj_id: int
    T_world_model: np.ndarray
    first_im: int
    gt_ids: dict[int, int]


def associate_instances(
    views: tuple[CameraView, ...],
    folder: SceneFolder,
    tracker: ResidualTracker,
    gt_paths: Mapping[int, Path] | None = None,
) -> list[GtObject]:
    """Static GT instances of a group of views, associated across the views' ``scene_gt`` lists.

    Images are visited in the given order. In each, the annotations of one ``obj_id`` are assigned
    to the known instances of that object by nearest world position (Hungarian assignment on
    ``|t_world|``); an annotation becomes a new instance only when the image holds more instances of
    the object than are known and it is farther than ``FAIL_MM`` from them. Every assigned pair is
    checked by ``tracker`` (``T_cam_world @ T_world_model`` vs the stored ``T_cam_model``), which
    raises on a gross mismatch (a frame mix-up) and records small rounding residuals.

    Args:
        gt_paths: per image id, the file its annotations came from (multi-sensor folders:
            ``scene_gt_{sensor}.json``); default the folder's ``scene_gt.json``.

    Returns:
        GtObjects in order of first appearance, with ``gt_ids`` and ``visib_fract`` per image.
    """
    instances: list[_Instance] = []
    for view in views:
        im, T_cw = view.im_id, view.T_cam_world
        gt_path = folder.path / SCENE_GT if gt_paths is None else gt_paths[im]
        entries = folder.gt[im]
        by_obj: dict[int, list[int]] = {}
        for gt_id, e in enumerate(entries):
            by_obj.setdefault(e.obj_id, []).append(gt_id)
        T_wc = invert_pose(T_cw)
        for obj_id, gt_ids in by_obj.items():
            T_wm = T_wc @ np.stack([entries[g].T_cam_model for g in gt_ids])  # (n, 4, 4)
            known = [inst for inst in instances if inst.obj_id == obj_id]
            matched = _assign(T_wm[:, :3, 3], known, allow_new=len(gt_ids) > len(known))
            for row, gt_id in enumerate(gt_ids):
                inst = matched.get(row)
                if inst is None:
                    instances.append(_Instance(obj_id, T_wm[row], im, {im: gt_id}))
                    continue
                tracker.check(
                    T_cw @ inst.T_world_model,
                    entries[gt_id].T_cam_model,
                    gt_path,
                    f"{im}[{gt_id}]",
                    f"T_cam_world @ T_world_model of the obj {obj_id} instance first seen in image {inst.first_im}",
                )
                inst.gt_ids[im] = gt_id

    def source(inst: _Instance) -> str:
        return str(folder.path / SCENE_GT if gt_paths is None else gt_paths[inst.first_im])

    return [
        GtObject(
            obj_id=inst.obj_id,
            T_world_model=inst.T_world_model,
            gt_ids=inst.gt_ids,
            visib_fract={} if folder.visib is None else {im: folder.visib[im][g] for im, g in inst.gt_ids.items()},
            T_cam_model={im: folder.gt[im][g].T_cam_model for im, g in inst.gt_ids.items()},
            source=source(inst),
        )
        for inst in instances
    ]


def _assign(t_new: np.ndarray, known: list[_Instance], allow_new: bool) -> dict[int, _Instance]:
    """Row of ``t_new (n, 3)`` -> known instance, by minimum total world distance (mm)."""
    if not known:
        return {}
    t_known = np.stack([inst.T_world_model[:3, 3] for inst in known])
    dist = np.linalg.norm(t_new[:, None, :] - t_known[None, :, :], axis=-1)  # (n, k)
    rows, cols = linear_sum_assignment(dist)
    return {int(r): known[c] for r, c in zip(rows, cols, strict=True) if not (allow_new and dist[r, c] > FAIL_MM)}
