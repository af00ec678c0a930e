"""Write a synthetic bin-picking dataset in the BOP-Industrial multi-sensor layout (docs/datasets.md,
"BOP-Industrial: multi-sensor splits"; the reader is :mod:`bop_cender.data.industrial`).

A scene is one bin (a render-only box open at the top, id 0, never in the GT) with a dense pile of 10-16 DIMO parts
(the DIMO catalogue's six parts, ids 1..6; each pile uses one to three of them), seen in ``n_images`` captures by
the four calibrated sensors of :data:`~bop_cender.data.industrial_params.SYNTH_INDUSTRIAL` (one table: names,
modalities, sizes): ``hires`` (gray, the evaluated sensor), ``left`` and ``right`` (RGB), ``tof`` (gray and depth).
The rig (:data:`RIG`) keeps its shape and turns about the bin from one capture to the next, as a robot-held rig.

Per split ``test/{s:06d}`` (s = 1..n) and ``train/{s:06d}`` (s = 0..m-1, other draws of the same seed) and per
sensor ``x``: ``scene_camera_x.json`` (``cam_K``, ``cam_R_w2c``/``cam_t_w2c``, ``depth_scale``), ``scene_gt_x.json``
(model-to-camera, every part of the pile, visible or not), ``scene_gt_info_x.json``
(:func:`bop_cender.synth.gt_info.object_visibility`), ``gray_x/`` (one channel) or ``rgb_x/``, ``depth_x/``
(uint16, ``depth_scale`` 0.1), ``mask_x/`` and ``mask_visib_x/``. At the root: ``models/`` and ``models_eval/``,
``test_targets_bop19.json`` and ``test_targets_bop24.json`` (the evaluated sensor's images, visib_fract >= 0.1).
The generator's record (``bop_cender_synth.json``, layout ``industrial``) is what lets ``--dataset bop`` know which
sensor is evaluated (:func:`bop_cender.data.industrial.synth_spec`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from bop_cender.data.bop_io import save_depth, save_json, write_image
from bop_cender.data.industrial_params import SYNTH_INDUSTRIAL
from bop_cender.data.layout import sensor_file, sensor_folder
from bop_cender.meshes import MeshCache
from bop_cender.synth.bop_files import Pile, camera_entry, gt_entry, scene_folder
from bop_cender.synth.contact_sheet import write_contact_sheet
from bop_cender.synth.gt_info import object_visibility
from bop_cender.synth.imaging import render_views
from bop_cender.synth.parts import Part, make_carrier
from bop_cender.synth.piles import PileGeometryCache, build_pile
from bop_cender.synth.rigs import _direction, intrinsics, look_at
from bop_cender.synth.styles import check_appearance, make_style
from bop_cender.synth.write_dimo import DIMO_CATALOGUE_SEED, dimo_models
from bop_cender.synth.write_tless import write_targets as write_bop_targets

DEPTH_SCALE = 0.1
#: The render-only bin (never in models/ nor in the GT, as T-LESS's table).
BIN_ID = 0
#: The bin's outer size (x, y, z) mm: a deep box open at the top.
BIN_SIZE = (360.0, 270.0, 120.0)
#: Radius (mm) of the disk of drop positions about the bin's centre: inside its pocket, so parts fall into the bin.
DROP_SPREAD_MM = 85.0
#: The rig looks at this world point (about the middle of the pile).
RIG_TARGET = (0.0, 0.0, 50.0)
#: Per sensor: azimuth offset (deg, about the bin from the capture's azimuth), elevation above the floor (deg),
#: distance to the target (mm), focal length in units of the image width. Sizes and modalities: SYNTH_INDUSTRIAL.
RIG = {
    "hires": (0.0, 72.0, 850.0, 1.45),
    "left": (50.0, 55.0, 800.0, 1.3),
    "right": (-50.0, 55.0, 800.0, 1.3),
    "tof": (180.0, 65.0, 750.0, 1.2),
}
#: Per-capture random motion of the rig: azimuth (all around) and distance / elevation / look-at jitter.
DISTANCE_JITTER_MM, ELEVATION_JITTER_DEG, TARGET_JITTER_MM = 40.0, 4.0, 15.0


@dataclass(frozen=True)
class IndustrialSynthSpec:
    """What to generate.

    Attributes:
        n_scenes: test scenes (ids 1..n). train_scenes: train scenes (ids 0..m-1).
        n_images: captures per scene (each: one image per sensor).
        parts_per_scene: (min, max) parts per bin.
        seed: piles, rig motion, light and materials derive from it. catalogue_seed: the DIMO catalogue's.
        appearance: the train folders' look (``default``: as test; ``randomised``: domain randomisation).
    """

    n_scenes: int = 2
    n_images: int = 3
    train_scenes: int = 1
    parts_per_scene: tuple[int, int] = (10, 16)
    seed: int = 0
    contact_sheets: bool = True
    catalogue_seed: int = DIMO_CATALOGUE_SEED
    appearance: str = "default"

    def __post_init__(self) -> None:
        check_appearance(self.appearance)
        lo, hi = self.parts_per_scene
        if not 1 <= lo <= hi <= 40:
            raise ValueError(f"parts per bin (--parts) must be MIN,MAX with 1 <= MIN <= MAX <= 40, got {lo},{hi}")
        if self.seed < 0 or self.catalogue_seed < 0:
            raise ValueError(f"seeds must be >= 0, got seed {self.seed}, catalogue_seed {self.catalogue_seed}")


def industrial_models(catalogue_seed: int = DIMO_CATALOGUE_SEED) -> dict[int, Part]:
    """The DIMO catalogue's parts (ids 1..6, its carriers left out) and the render-only bin (id 0)."""
    models = {i: p for i, p in dimo_models(catalogue_seed).items() if i in SYNTH_INDUSTRIAL.obj_ids}
    models[BIN_ID] = make_carrier(np.random.default_rng([catalogue_seed, 11]), BIN_SIZE)
    return models


def scene_jobs(spec: IndustrialSynthSpec) -> list[tuple[str, int]]:
    """Independent units of work: ``("test", 1..n)`` and ``("train", 0..m-1)``."""
    return [("test", s + 1) for s in range(spec.n_scenes)] + [("train", s) for s in range(spec.train_scenes)]


def job_folders(root: Path, job: tuple[str, int]) -> list[Path]:
    return [Path(root) / job[0] / f"{job[1]:06d}"]


def rig_cameras(rng: np.random.Generator, n_images: int) -> list[dict[str, tuple[np.ndarray, np.ndarray]]]:
    """Per capture, per sensor ``(K (3, 3), T_cam_world (4, 4))``: the rig of :data:`RIG` turned to a uniform
    azimuth, each sensor's distance, elevation and look-at point jittered."""
    captures = []
    for _ in range(n_images):
        azimuth = rng.uniform(0.0, 360.0)
        cams = {}
        for sensor in SYNTH_INDUSTRIAL.sensors:
            d_az, elev, dist, f = RIG[sensor.name]
            width, height = sensor.image_size
            elev = elev + rng.uniform(-ELEVATION_JITTER_DEG, ELEVATION_JITTER_DEG)
            dist = dist + rng.uniform(-DISTANCE_JITTER_MM, DISTANCE_JITTER_MM)
            target = np.asarray(RIG_TARGET) + rng.uniform(-TARGET_JITTER_MM, TARGET_JITTER_MM, 3)
            eye = target + dist * _direction(np.deg2rad(azimuth + d_az), np.deg2rad(elev))
            K = intrinsics(f * width, f * width, width / 2.0, height / 2.0)
            cams[sensor.name] = (K, look_at(eye, target))
        captures.append(cams)
    return captures


def write_scene(
    root: Path,
    spec: IndustrialSynthSpec,
    job: tuple[str, int],
    models: dict[int, Part],
    meshes: MeshCache,
    piles: PileGeometryCache | None = None,
) -> int:
    """Write one scene folder (skipped if done, :mod:`bop_cender.synth.done`). Returns folders written."""
    split, s = job
    sheet_path = Path(root) / "contact_sheets" / f"{split}_{s:06d}.png"
    with scene_folder(job_folders(root, job)[0], extra=[sheet_path]) as tmp:
        if tmp is None:
            return 0
        rng = np.random.default_rng([spec.seed, 1 if split == "test" else 2, s])
        part_ids = sorted(i for i in models if i != BIN_ID)
        n = int(rng.integers(spec.parts_per_scene[0], spec.parts_per_scene[1] + 1))
        types = sorted(int(t) for t in rng.choice(len(part_ids), size=int(rng.integers(1, 4)), replace=False))
        placed = build_pile([models[i].mesh for i in part_ids], models[BIN_ID].mesh, np.eye(4), n, rng,
                            composition=types, spread=DROP_SPREAD_MM, cache=piles)  # fmt: skip
        pile = Pile(
            obj_ids=[BIN_ID] + [part_ids[p.part_index] for p in placed],
            T_world_model=np.stack([np.eye(4)] + [p.T_world_model for p in placed]),
            gt_indices=list(range(1, len(placed) + 1)),
        )
        captures = rig_cameras(rng, spec.n_images)
        domain = "randomised" if split == "train" and spec.appearance == "randomised" else "sim"
        centre = pile.T_world_model[:, :3, 3].mean(axis=0)
        style = make_style(rng, domain, len(pile.obj_ids), centre, carrier_index=0)
        mesh_list = meshes.many(pile.obj_ids)
        sheet = []
        for sensor in SYNTH_INDUSTRIAL.sensors:
            name, (width, height) = sensor.name, sensor.image_size
            cams = [c[name] for c in captures]
            views = render_views(mesh_list, pile.T_world_model, cams, height, width, style, rng)
            first = views[0]
            if sensor.intensity == "gray":  # the sheet shows what the sensor wrote
                first = replace(first, rgb=np.repeat(_gray(first.rgb)[..., None], 3, axis=-1))
            sheet.append(first)
            cameras, gts, infos = {}, {}, {}
            for im, ((K, T_cw), view) in enumerate(zip(cams, views, strict=True)):
                T_cm = np.einsum("ij,mjk->mik", T_cw, pile.T_world_model)
                vis = object_visibility(mesh_list, T_cm, K, view.instance, view.depth, pile.gt_indices)
                stem = f"{im:06d}"
                if "rgb" in sensor.modalities:
                    write_image(tmp / sensor_folder("rgb", name) / f"{stem}.png", view.rgb)
                if "gray" in sensor.modalities:
                    write_image(tmp / sensor_folder("gray", name) / f"{stem}.png", _gray(view.rgb))
                if "depth" in sensor.modalities:
                    save_depth(tmp / sensor_folder("depth", name) / f"{stem}.png", view.depth, DEPTH_SCALE)
                for gt_id, v in enumerate(vis):
                    mask_name = f"{stem}_{gt_id:06d}.png"
                    write_image(tmp / sensor_folder("mask", name) / mask_name, v.mask.astype(np.uint8) * 255)
                    write_image(
                        tmp / sensor_folder("mask_visib", name) / mask_name, v.mask_visib.astype(np.uint8) * 255
                    )
                cameras[im] = camera_entry(K, T_cw, with_c2w=False, depth_scale=DEPTH_SCALE)
                gts[im] = [gt_entry(pile.obj_ids[i], T_cm[i]) for i in pile.gt_indices]
                infos[im] = [v.info for v in vis]
            save_json(tmp / sensor_file("scene_camera", name), cameras)
            save_json(tmp / sensor_file("scene_gt", name), gts)
            save_json(tmp / sensor_file("scene_gt_info", name), infos)
        if spec.contact_sheets:  # one row per sensor: its first capture
            write_contact_sheet(sheet_path, sheet, len(sheet))
    return 1


def _gray(rgb: np.ndarray) -> np.ndarray:
    """One-channel uint8 luminance (ITU-R BT.601 weights) of an RGB uint8 image."""
    y = rgb.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
    return np.clip(np.round(y), 0, 255).astype(np.uint8)


def write_targets(root: Path) -> int:
    """``test_targets_bop19.json`` and ``test_targets_bop24.json`` of the evaluated sensor's test images (read back
    from the files, so a resumed run writes the same); the number of BOP'19 targets."""
    eval_sensor = SYNTH_INDUSTRIAL.eval_sensor
    return write_bop_targets(
        root,
        split_folder="test",
        gt_file=sensor_file("scene_gt", eval_sensor),
        info_file=sensor_file("scene_gt_info", eval_sensor),
    )
