"""One multi-sensor scene folder -> validated per-sensor cameras and GT, and the loader that makes its Scenes.

A BOP-Industrial scene folder (docs/datasets.md, "BOP-Industrial: multi-sensor splits") holds, per sensor ``s``,
``scene_camera_s.json``, ``scene_gt_s.json``, optionally ``scene_gt_info_s.json``, and image folders
``{modality}_s/`` (``gray_xyz/``, ``rgb_cam1/``, ``depth_photoneo/``, ``mask_visib_s/``). Every sensor's files are
checked as :func:`bop_cender.data.bop_scene.read_scene_folder` checks a single-sensor folder (same image ids in its
three files, pinhole ``cam_K``, rotations, known object ids, visibility lists), and every sensor's camera file must
list the same image ids: image ``im`` of every sensor is one capture of one static scene.

A Scene is one capture: the image ``im`` of every sensor, the evaluated sensor's first. Its views' ``im_id`` must be
unique in the Scene, so only the evaluated view keeps the BOP image id; the view of the ``k``-th other sensor has
the view id ``k * VIEW_ID_STRIDE + im`` (:func:`view_id`), ``evaluated`` False, and its BOP id in
``info["bop_im_id"]``. GT instances are associated across the sensors by their world poses (``cam_R_w2c``,
``cam_t_w2c``, required where a capture has several views) and checked, as across the views of a single-sensor group.
"""

from __future__ import annotations

import os
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from bop_cender.data.bop_io import check_same_image_ids, few_ids, load_image_dict, require_file
from bop_cender.data.bop_scene import (
    IMAGE_SUFFIXES,
    GtEntry,
    ImageCamera,
    SceneFolder,
    ScenePlan,
    associate_instances,
    parse_camera,
    parse_gt,
    parse_visib,
)
from bop_cender.data.consistency import ResidualTracker
from bop_cender.data.layout import SENSOR_FOLDER_MODALITIES, sensor_file, sensor_folder
from bop_cender.data.types import CameraView, Scene, Sensor
from bop_cender.errors import DatasetError

#: View ids of the other sensors' views: ``k * VIEW_ID_STRIDE + im`` (BOP image ids have six digits).
VIEW_ID_STRIDE = 1_000_000
#: Depth image suffixes (ITODD-MV writes TIFF).
DEPTH_SUFFIXES = (".png", ".tif")
#: How many parsed scene folders a loader keeps.
FOLDER_CACHE_SIZE = 2


def view_id(sensor_index: int, im_id: int) -> int:
    """The id in its Scene of the view of sensor ``sensor_index`` (0: the evaluated one, whose id is the BOP id)."""
    return sensor_index * VIEW_ID_STRIDE + im_id


@dataclass(frozen=True)
class SensorFolder:
    """One sensor's validated files in one scene folder.

    Attributes:
        sensor: the sensor.
        camera_path, gt_path, info_path: its ``scene_camera_s.json``, ``scene_gt_s.json``, ``scene_gt_info_s.json``.
        cameras: per image id, its camera. gt: per image id, its annotations (index = gt_id).
        visib: per image id, ``visib_fract`` per gt_id; None without ``scene_gt_info_s.json``.
        listing: per image or mask modality with a folder ``{modality}_s/``, its file names.
    """

    sensor: Sensor
    camera_path: Path
    gt_path: Path
    info_path: Path
    cameras: dict[int, ImageCamera]
    gt: dict[int, list[GtEntry]]
    visib: dict[int, list[float]] | None
    listing: dict[str, frozenset[str]]


def parse_sensor_camera(entry: Any, im: int, path: Path) -> ImageCamera:
    """A ``scene_camera_s.json`` entry; a BOP'24 ``cam_model`` (a non-pinhole projection) cannot be projected by this
    project, and the toolkit refuses an entry with both ``cam_K`` and ``cam_model``.

    Raises:
        DatasetError: naming the file and the entry's field.
    """
    if isinstance(entry, Mapping) and "cam_model" in entry:
        if "cam_K" in entry:
            raise DatasetError(
                "has both cam_K and cam_model; expected one of them", file=path, field=f"{im}: cam_model"
            )
        model = entry["cam_model"]
        kind = model.get("projection_model_type", "unnamed") if isinstance(model, Mapping) else type(model).__name__
        raise DatasetError(
            f"a camera model ({kind}) without cam_K: this project projects with a pinhole cam_K only",
            file=path,
            field=f"{im}: cam_model",
        )
    return parse_camera(entry, im, path, None)


def read_sensor_folder(scene_dir: Path, sensor: Sensor, obj_ids: Collection[int]) -> SensorFolder:
    """Read and check one sensor's files in ``scene_dir`` (see the module docstring)."""
    name = sensor.name
    cam_path = require_file(scene_dir / sensor_file("scene_camera", name), f"camera file of sensor {name}")
    gt_path = scene_dir / sensor_file("scene_gt", name)
    info_path = scene_dir / sensor_file("scene_gt_info", name)
    cam_raw, gt_raw = load_image_dict(cam_path), load_image_dict(gt_path)
    check_same_image_ids({cam_path: cam_raw, gt_path: gt_raw})
    cameras = {im: parse_sensor_camera(cam_raw[im], im, cam_path) for im in cam_raw}
    gt = {im: parse_gt(gt_raw[im], im, gt_path, obj_ids) for im in gt_raw}
    visib = None
    if info_path.is_file():
        info_raw = load_image_dict(info_path)
        check_same_image_ids({cam_path: cam_raw, info_path: info_raw})
        visib = {im: parse_visib(info_raw[im], len(gt[im]), im, info_path) for im in info_raw}
    listing = {}
    for modality in SENSOR_FOLDER_MODALITIES:
        folder = scene_dir / sensor_folder(modality, name)
        if folder.is_dir():
            listing[modality] = frozenset(os.listdir(folder))
    return SensorFolder(sensor, cam_path, gt_path, info_path, cameras, gt, visib, listing)


def read_capture_folder(scene_dir: Path, sensors: tuple[Sensor, ...], obj_ids: Collection[int]) -> list[SensorFolder]:
    """Every sensor's files of one scene folder; their camera files must list the same image ids."""
    folders = [read_sensor_folder(scene_dir, s, obj_ids) for s in sensors]
    check_same_image_ids({f.camera_path: f.cameras for f in folders})
    return folders


@dataclass
class IndustrialSceneLoader:
    """The lazy ``Dataset.loader`` of a multi-sensor split: scene key -> the Scene of one capture.

    Attributes:
        sensors: the split's sensors, the evaluated one first.
        residuals: the Dataset's residual dict, updated after each load (as :class:`BopSceneLoader` does).
    """

    dataset: str
    split: str
    split_dir: Path
    plans: dict[str, ScenePlan]
    sensors: tuple[Sensor, ...]
    obj_ids: frozenset[int]
    residuals: dict[str, float]
    tracker: ResidualTracker = field(default_factory=ResidualTracker)
    _folders: dict[str, list[SensorFolder]] = field(default_factory=dict, repr=False)

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_folders"] = {}
        return state

    def __call__(self, key: str) -> Scene:
        plan = self.plans[key]
        (im,) = plan.im_ids
        folders = self._folder(plan.scene_id)
        if im not in folders[0].cameras:
            raise DatasetError(
                f"image {im} was listed when the dataset was opened but is gone", file=folders[0].camera_path
            )
        several = len(folders) > 1
        views = tuple(self._view(k, f, im, several) for k, f in enumerate(folders))
        ids = [v.im_id for v in views]
        merged = SceneFolder(
            path=self.split_dir / plan.scene_id,
            cameras={v: f.cameras[im] for v, f in zip(ids, folders, strict=True)},
            gt={v: f.gt[im] for v, f in zip(ids, folders, strict=True)},
            visib=None,
            listing={},
        )
        gt_paths = {v: f.gt_path for v, f in zip(ids, folders, strict=True)}
        gt = associate_instances(views, merged, self.tracker, gt_paths)
        visib = {v: f.visib[im] for v, f in zip(ids, folders, strict=True) if f.visib is not None}
        gt = [replace(g, visib_fract={v: visib[v][n] for v, n in g.gt_ids.items() if v in visib}) for g in gt]
        self.residuals.update(
            gt_max_mm=self.tracker.max_mm, gt_max_rad=self.tracker.max_rad, gt_pairs=float(self.tracker.count)
        )
        self.tracker.report(f"{self.dataset} {self.split_dir.name}: GT poses across sensors")
        info = {"split_folder": self.split_dir.name, "eval_sensor": self.sensors[0].name, "bop_im_id": im}
        return Scene(self.dataset, self.split, plan.scene_id, views, tuple(gt), plan.key_suffix, info)

    def _folder(self, scene_id: str) -> list[SensorFolder]:
        if scene_id not in self._folders:
            if len(self._folders) >= FOLDER_CACHE_SIZE:
                self._folders.pop(next(iter(self._folders)))
            self._folders[scene_id] = read_capture_folder(self.split_dir / scene_id, self.sensors, self.obj_ids)
        return self._folders[scene_id]

    def _view(self, k: int, folder: SensorFolder, im: int, several: bool) -> CameraView:
        cam, name = folder.cameras[im], folder.sensor.name
        if cam.T_cam_world is None and several:
            raise DatasetError(
                "missing cam_R_w2c/cam_t_w2c: the sensors of one capture are related by their world poses",
                file=folder.camera_path,
                field=str(im),
            )
        stem = f"{im:06d}"
        modality = folder.sensor.intensity
        depth = _file(folder, "depth", stem, DEPTH_SUFFIXES)
        if depth is not None and cam.depth_scale is None:
            raise DatasetError(
                f"missing key 'depth_scale' (needed for {depth.name})", file=folder.camera_path, field=str(im)
            )
        extra = {m: _file(folder, m, stem, IMAGE_SUFFIXES) for m in folder.sensor.modalities if m in ("aolp", "dolp")}
        n_gt = len(folder.gt[im])
        info = {**cam.info, "modality": modality, "bop_im_id": im}
        if any(p is not None for p in extra.values()):
            info["images"] = {m: p for m, p in extra.items() if p is not None}
        return CameraView(
            im_id=view_id(k, im),
            K=cam.K,
            T_cam_world=np.eye(4) if cam.T_cam_world is None else cam.T_cam_world,
            width=folder.sensor.image_size[0],
            height=folder.sensor.image_size[1],
            rgb_path=None if modality is None else _file(folder, modality, stem, IMAGE_SUFFIXES),
            depth_path=depth,
            depth_scale=cam.depth_scale,
            mask_paths=_masks(folder, "mask", im, n_gt),
            mask_visib_paths=_masks(folder, "mask_visib", im, n_gt),
            info=info,
            source=str(folder.camera_path),
            sensor=name,
            evaluated=k == 0,
        )


def _file(folder: SensorFolder, modality: str, stem: str, suffixes: tuple[str, ...]) -> Path | None:
    """The image ``stem`` of ``{modality}_s/``; None when the sensor has no such folder."""
    if modality not in folder.listing:
        return None
    sub = folder.camera_path.parent / sensor_folder(modality, folder.sensor.name)
    for ext in suffixes:
        if stem + ext in folder.listing[modality]:
            return sub / (stem + ext)
    raise DatasetError(f"image missing (expected {stem} with suffix {'/'.join(suffixes)})", file=sub)


def _masks(folder: SensorFolder, modality: str, im: int, n_gt: int) -> tuple[Path, ...]:
    if modality not in folder.listing:
        return ()
    sub = folder.camera_path.parent / sensor_folder(modality, folder.sensor.name)
    names = [f"{im:06d}_{gt_id:06d}.png" for gt_id in range(n_gt)]
    missing = [n for n in names if n not in folder.listing[modality]]
    if missing:
        raise DatasetError(
            f"mask missing (expected one per annotation of {folder.gt_path.name}; {few_ids(missing)})", file=sub
        )
    return tuple(sub / n for n in names)
