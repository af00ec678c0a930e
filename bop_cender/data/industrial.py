"""Open a BOP-Industrial multi-sensor split (IPD, XYZ-IBD, ITODD-MV) as Scenes of one capture each.

The layout (docs/datasets.md, "BOP-Industrial: multi-sensor splits"): a scene folder holds, per sensor ``s``,
``scene_camera_s.json``, ``scene_gt_s.json``, ``scene_gt_info_s.json`` and image folders ``{modality}_s/``; one sensor
is the evaluated one (IPD ``photoneo``, XYZ-IBD ``xyz``, ITODD-MV ``3dlong``): the targets files and the results
rows name its images, in its camera frame. The constants are :mod:`bop_cender.data.industrial_params`'s table.

What happens at open time (cheap: one directory listing and the evaluated sensor's camera file per scene folder,
one image header per sensor and modality):

1. The split folder is resolved as for any BOP split; :func:`multi_sensor_folder` tells this layout from the
   classic one (``scene_camera_*.json`` and no ``scene_camera.json``).
2. The sensors are those with a camera file; every scene folder must have all of them, and an image folder
   ``{modality}_s/`` needs its sensor's camera file. For a named dataset they must be the table's sensors and
   include its evaluated one, and the models its object ids.
3. The first image of each sensor and image modality must have the sensor's size (the table's; without a table,
   the first image's) and its modality's channels (gray: one; rgb: three or four).
4. The targets select the evaluated sensor's images as :func:`bop_cender.data.bop.select_images` does:
   ``test_targets_bop19.json`` and ``test_targets_bop24.json``. The toolkit at the commit the table cites
   (thodan/bop_toolkit @ cea62d6) defines no BOP'25 multi-view targets file (only the ``bop25_mAP`` score name
   of ``eval_bop24_pose.py``), so none is read: each selected image is one capture's Scene.
5. One Scene per selected capture, key ``{scene}/i{im:06d}`` (:mod:`bop_cender.data.industrial_scene`).
"""

from __future__ import annotations

import json
from pathlib import Path

from bop_cender.data.bop import SplitLayout, load_model_sets, resolve_split_folder, scene_folders, select_images
from bop_cender.data.bop_io import image_shape, load_image_dict, require_dir
from bop_cender.data.bop_scene import IMAGE_SUFFIXES, ScenePlan
from bop_cender.data.file_checks import MODALITY_CHANNELS
from bop_cender.data.industrial_params import INDUSTRIAL, SYNTH_INDUSTRIAL, IndustrialSpec
from bop_cender.data.industrial_scene import DEPTH_SUFFIXES, IndustrialSceneLoader
from bop_cender.data.layout import (
    SCENE_CAMERA,
    SENSOR_CAMERA_PREFIX,
    SENSOR_FOLDER_MODALITIES,
    SYNTH_RECORD,
    sensor_file,
    sensor_folder,
)
from bop_cender.data.types import Dataset, ObjectModel, Sensor
from bop_cender.errors import ConfigError, DatasetError


def multi_sensor_folder(root: Path, split: str, split_type: str | None = None) -> str | None:
    """The split folder of ``split`` when it is in the multi-sensor layout (its first scene folder has a
    ``scene_camera_*.json`` and no ``scene_camera.json``), else None (also when the folder cannot be resolved: the
    classic loader then says why)."""
    try:
        folder = resolve_split_folder(Path(root), split, split_type)
        scenes = sorted(p for p in (Path(root) / folder).iterdir() if p.is_dir() and p.name.isdigit())
        if not scenes or (scenes[0] / SCENE_CAMERA).is_file():
            return None
        return folder if any(scenes[0].glob(f"{SENSOR_CAMERA_PREFIX}*.json")) else None
    except (ConfigError, OSError):
        return None


def config_layout(dataset: str, data_root: str | Path | None, split: str) -> str:
    """The name the method's settings and centre targets are made for (``CenDerNetConfig.for_dataset``,
    ``TargetConfig.for_dataset``): ``dataset``, except ``industrial`` for a ``bop`` folder in the multi-sensor layout
    (bin-picking piles: their own centre targets). The one place ``run``, ``train`` and ``heatmaps`` choose it."""
    if dataset == "bop" and data_root is not None and multi_sensor_folder(Path(data_root), split) is not None:
        return "industrial"
    return dataset


def open_industrial(
    root: str | Path,
    split: str,
    *,
    name: str | None = None,
    folder: str | None = None,
    spec: IndustrialSpec | None = None,
    model_type: str | None = None,
    split_type: str | None = None,
) -> Dataset:
    """Open a multi-sensor split.

    Args:
        root: dataset root (``models*/``, split folders, targets files).
        split: ``test``, ``val``, ... or a literal split folder name.
        name: dataset name; defaults to the root folder's name. Its constants are ``spec``, else the table's entry
            for it, else :data:`SYNTH_INDUSTRIAL` for a set ``bop-cender synth --layout industrial`` wrote
            (:func:`synth_spec`); without any, the sensors' sizes are their first images' and the evaluated sensor must be
            the only one.
        folder: the split folder, when already resolved.
        model_type: use ``models_{model_type}/`` instead of ``models/``.
        split_type: use the folder ``{split}_{split_type}``.

    Raises:
        ConfigError: unknown split or models folder, or an unnamed dataset of several sensors.
        DatasetError: missing or inconsistent files (each naming the file and the field).
    """
    root = require_dir(root, "dataset root folder")
    name = name or root.resolve().name
    spec = spec or INDUSTRIAL.get(name) or synth_spec(root)
    folder = folder or resolve_split_folder(root, split, split_type)
    split_dir = root / folder
    layout = SplitLayout(folder=folder, models_dir=f"models_{model_type}" if model_type else "models")
    notes = [f"split {split!r}: folder {folder}/ (multi-sensor: scene_camera_<sensor>.json per sensor)"]
    models, eval_models = load_model_sets(root, layout, notes)
    scene_ids = scene_folders(split_dir)
    sensors = _sensors(split_dir, scene_ids, spec, name)
    _check_models(root / layout.models_dir, models, spec, notes)
    eval_camera = sensor_file("scene_camera", sensors[0].name)
    index = {sid: _camera_index(split_dir / sid / eval_camera) for sid in scene_ids}
    selected = select_images(root, index, models, layout, notes)
    plans = {
        f"{sid}/i{im:06d}": ScenePlan(sid, f"i{im:06d}", (im,), multi_view=len(sensors) > 1)
        for sid, ims in selected.items()
        for im in ims
    }
    notes.append(
        f"one Scene per capture: image im of every sensor ({', '.join(s.name for s in sensors)}); the evaluated"
        f" sensor {sensors[0].name}'s images are the BOP images (results rows, scoring): {len(plans)} scenes"
    )
    residuals: dict[str, float] = {}
    loader = IndustrialSceneLoader(name, split, split_dir, plans, sensors, frozenset(models), residuals)
    has_depth = (split_dir / scene_ids[0] / sensor_folder("depth", sensors[0].name)).is_dir()
    return Dataset(
        root=root, name=name, split=split, models=models, scene_keys=list(plans), loader=loader,
        eval_models=eval_models, selection=notes, residuals=residuals, image_size=sensors[0].image_size,
        has_depth=has_depth, split_dir=split_dir, sensors=sensors, eval_sensor=sensors[0].name,
        scene_camera_name=eval_camera,
    )  # fmt: skip


def synth_spec(root: Path) -> IndustrialSpec | None:
    """:data:`SYNTH_INDUSTRIAL` where ``root`` holds the record of ``bop-cender synth --layout industrial``
    (``bop_cender_synth.json``, ``"layout": "industrial"``), else None: its sensors are that table's, whatever the
    root folder is called."""
    try:
        record = json.loads((Path(root) / SYNTH_RECORD).read_text())
    except (OSError, ValueError):
        return None
    return SYNTH_INDUSTRIAL if isinstance(record, dict) and record.get("layout") == "industrial" else None


def _camera_index(path: Path) -> dict[int, bool]:
    """Image ids of the evaluated sensor's camera file (the value: unused, as :func:`select_images` takes it)."""
    return dict.fromkeys(load_image_dict(path), True)


def _sensor_folders(scene_dir: Path) -> dict[str, set[str]]:
    """Sensor -> the modalities of its image and mask folders ``{modality}_{sensor}/`` in one scene folder."""
    found: dict[str, set[str]] = {}
    for p in scene_dir.iterdir():
        if p.is_dir():
            for modality in SENSOR_FOLDER_MODALITIES:
                if p.name.startswith(modality + "_"):
                    found.setdefault(p.name[len(modality) + 1 :], set()).add(modality)
                    break
    return found


def _sensors(split_dir: Path, scene_ids: list[str], spec: IndustrialSpec | None, name: str) -> tuple[Sensor, ...]:
    """The split's sensors, the evaluated one first, each with its modalities and image size (see the module)."""
    cameras: dict[str, set[str]] = {}  # scene folder -> sensors with a camera file
    folders: dict[str, dict[str, set[str]]] = {}
    for sid in scene_ids:
        scene_dir = split_dir / sid
        cameras[sid] = {p.name[len(SENSOR_CAMERA_PREFIX) : -5] for p in scene_dir.glob(f"{SENSOR_CAMERA_PREFIX}*.json")}
        folders[sid] = _sensor_folders(scene_dir)
    names = set().union(*cameras.values())
    for sid in scene_ids:  # every sensor in every scene folder; an image folder needs its sensor's camera file
        for sensor in sorted(names - cameras[sid]) + sorted(set(folders[sid]) - names):
            raise DatasetError(
                f"camera file of sensor {sensor} missing (every scene folder needs one per sensor: "
                f"{', '.join(sorted(names)) or 'none found'})",
                file=split_dir / sid / sensor_file("scene_camera", sensor),
                field=f"sensor {sensor}",
            )
    first = split_dir / scene_ids[0]
    if spec is None:
        if len(names) != 1:
            raise ConfigError(
                f"a multi-sensor split of sensors {', '.join(sorted(names))}: which one is evaluated is unknown for"
                f" dataset {name!r}; name the dataset (--dataset {'|'.join(INDUSTRIAL)}) or its root folder after it",
                file=split_dir,
                field="--dataset",
            )
        (sensor,) = names
        modalities = tuple(sorted(folders[scene_ids[0]].get(sensor, set()) & {"rgb", "gray", "depth", "aolp", "dolp"}))
        return (_checked(first, Sensor(sensor, modalities, (0, 0)), from_images=True),)
    known = [s.name for s in spec.sensors]
    for sensor in sorted(names - set(known)):
        raise DatasetError(
            f"sensor {sensor} is not one of {spec.name}'s sensors ({', '.join(known)})",
            file=first / sensor_file("scene_camera", sensor),
            field="sensor",
        )
    if spec.eval_sensor not in names:
        raise DatasetError(
            f"camera file of the evaluated sensor {spec.eval_sensor} missing", file=first / sensor_file(
                "scene_camera", spec.eval_sensor), field=f"sensor {spec.eval_sensor}",
        )  # fmt: skip
    return tuple(_checked(first, s) for s in spec.sensors if s.name in names)


def _checked(scene_dir: Path, sensor: Sensor, from_images: bool = False) -> Sensor:
    """``sensor`` once the first image of each of its image folders in ``scene_dir`` has its size (with
    ``from_images``: the size of the first such image) and its modality's channels."""
    size = None if from_images else sensor.image_size
    for modality in sensor.modalities:
        sub = scene_dir / sensor_folder(modality, sensor.name)
        suffixes = DEPTH_SUFFIXES if modality == "depth" else IMAGE_SUFFIXES
        images = sorted(p for p in sub.glob("*") if p.suffix.lower() in suffixes) if sub.is_dir() else []
        if not images:
            continue
        width, height, channels = image_shape(images[0])
        if size is None:
            size = (width, height)
        if (width, height) != size:
            source = "the first image's" if from_images else "the table's (the toolkit's dataset_params.py)"
            raise DatasetError(
                f"image is {width}x{height}, expected {size[0]}x{size[1]} for sensor {sensor.name}: {source} size",
                file=images[0],
                field="size",
            )
        if modality in MODALITY_CHANNELS and channels not in MODALITY_CHANNELS[modality]:
            raise DatasetError(
                f"a {channels}-channel image where {modality} is expected ({' or '.join(map(str, MODALITY_CHANNELS[modality]))}"
                f" channels)",
                file=images[0],
                field="channels",
            )
    if size is None:
        raise DatasetError(f"no image of sensor {sensor.name} to tell its size from", file=scene_dir)
    return Sensor(sensor.name, sensor.modalities, size)


def _check_models(
    models_dir: Path, models: dict[int, ObjectModel], spec: IndustrialSpec | None, notes: list[str]
) -> None:
    """The models must be among the table's object ids (IPD's start at 0); where their ``models_info.json``
    symmetries and the table's symmetric ids differ, a note says so (scores follow the symmetries)."""
    if spec is None:
        return
    unknown = sorted(set(models) - set(spec.obj_ids))
    if unknown:
        raise DatasetError(
            f"object(s) {unknown} are not {spec.name}'s (ids {', '.join(map(str, spec.obj_ids))})",
            file=models_dir / "models_info.json",
            field="obj_id",
        )
    if spec.symmetric_obj_ids is None:  # a synthetic catalogue: models_info.json is the only list
        return
    symmetric = sorted(i for i, m in models.items() if m.is_symmetric)
    listed = sorted(set(spec.symmetric_obj_ids) & set(models))
    if symmetric != listed:
        notes.append(
            f"symmetric objects: {symmetric or 'none'} by models_info.json, {listed or 'none'} by the toolkit's"
            f" {spec.name} table; scores use the symmetries of models_info.json"
        )
