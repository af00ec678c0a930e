"""Build small, self-consistent DIMO folders for tests (random but seeded poses).

The builder writes the files with plain ``json`` and ``np.linalg.inv`` (not the project's
writers or pose helpers), so a test compares the loader against an independent writer.
Viewpoint ``k`` gets the same camera pose in every scene (DIMO's fixed robot viewpoints).

Import from other tests as ``dimo_builder`` (pytest puts ``tests/data`` on ``sys.path``) or as
``tests.data.dimo_builder`` when the repository root is on the path.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

#: Box models (size x, y, z in mm) by object id; 100 is a flat carrier.
MODEL_SIZES: dict[int, tuple[float, float, float]] = {
    1: (20.0, 20.0, 20.0),
    2: (30.0, 10.0, 10.0),
    100: (200.0, 200.0, 10.0),
}


@dataclass
class SceneSpec:
    """What to write for one scene folder.

    Attributes:
        folder: folder name (``000000`` or ``000000_17``).
        camera_dir: ``real_jaigo`` or ``sim_jaigo``.
        viewpoints: one image per entry (image id = position), with that viewpoint id.
        carrier, parts, light: ``scene_info`` values for every image.
        obj_ids: object instances of the scene (``scene_gt_world.json`` order).
        camera_keys: ``c2w``, ``w2c`` or ``both`` (written consistently).
        old_info_keys: write ``carrier_id``/``composition_type``/... with string values.
        image_size: (width, height) of the rgb PNGs.
        focal_factor: fx = fy = focal_factor * width.
    """

    folder: str
    camera_dir: str = "real_jaigo"
    viewpoints: tuple[int, ...] = (0, 1, 2)
    carrier: int = 2
    parts: int = 1
    light: int = 0
    obj_ids: tuple[int, ...] = (1, 2, 100)
    camera_keys: str = "both"
    old_info_keys: bool = False
    image_size: tuple[int, int] = (16, 12)
    focal_factor: float = 2.0


@dataclass
class SceneTruth:
    """What was written: ``T_world_cam (4, 4)`` per image id and ``(obj_id, T_world_model (4, 4))`` per instance."""

    scene_dir: Path
    T_world_cam: dict[int, np.ndarray] = field(default_factory=dict)
    objects: list[tuple[int, np.ndarray]] = field(default_factory=list)


def random_pose(rng: np.random.Generator, t_center: Iterable[float], t_spread: float) -> np.ndarray:
    """A ``(4, 4)`` pose with a uniform random rotation and a translation within ``t_spread`` of ``t_center``."""
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    T[:3, 3] = np.asarray(list(t_center), dtype=float) + rng.uniform(-t_spread, t_spread, 3)
    return T


def viewpoint_pose(viewpoint: int, seed: int = 0) -> np.ndarray:
    """The camera-to-world pose of viewpoint ``viewpoint``: the same in every scene."""
    return random_pose(np.random.default_rng([seed, 1000 + viewpoint]), (0.0, 0.0, 500.0), 150.0)


def write_models(
    root: Path, obj_ids: Iterable[int] = tuple(MODEL_SIZES), meshes: dict[int, trimesh.Trimesh] | None = None
) -> None:
    """``models/models_info.json`` and ASCII box PLYs; object 1 gets a 90-degree z symmetry.

    ``meshes`` replaces the box of an object id by another mesh (centred on its bounding box).
    """
    models = root / "models"
    models.mkdir(parents=True, exist_ok=True)
    info = {}
    for obj_id in obj_ids:
        if meshes and obj_id in meshes:
            mesh = meshes[obj_id]
            size = np.asarray(mesh.bounds[1] - mesh.bounds[0])
        else:
            size = np.asarray(MODEL_SIZES[obj_id])
            mesh = trimesh.creation.box(extents=size)
        (models / f"obj_{obj_id:06d}.ply").write_bytes(trimesh.exchange.ply.export_ply(mesh, encoding="ascii"))
        entry: dict[str, Any] = {"diameter": float(np.linalg.norm(size))}
        entry.update({f"min_{a}": float(lo) for a, lo in zip("xyz", mesh.bounds[0], strict=True)})
        entry.update({f"size_{a}": float(s) for a, s in zip("xyz", size, strict=True)})
        if obj_id == 1 and not (meshes and obj_id in meshes):
            entry["symmetries_discrete"] = [[0, -1, 0, 0, 1, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]]
        info[str(obj_id)] = entry
    (models / "models_info.json").write_text(json.dumps(info, indent=1))


def write_scene(
    root: Path,
    spec: SceneSpec,
    rng: np.random.Generator,
    seed: int = 0,
    camera_pose: Callable[[int, int], np.ndarray] | None = None,
    object_poses: list[np.ndarray] | None = None,
) -> SceneTruth:
    """Write one scene folder from ``spec``; object poses from ``rng`` (or ``object_poses``, in
    ``spec.obj_ids`` order), cameras from their viewpoint (``camera_pose(viewpoint, seed)`` ->
    ``T_world_cam``; default :func:`viewpoint_pose`)."""
    camera_pose = camera_pose or viewpoint_pose
    scene_dir = root / spec.camera_dir / spec.folder
    (scene_dir / "rgb").mkdir(parents=True, exist_ok=True)
    truth = SceneTruth(scene_dir)
    for k, obj_id in enumerate(spec.obj_ids):
        if object_poses is not None:
            T = np.asarray(object_poses[k], dtype=float)
        elif obj_id >= 100:
            T = np.eye(4)
            T[2, 3] = -5.0
        else:
            T = random_pose(rng, (0.0, 0.0, 20.0), 60.0)
        truth.objects.append((obj_id, T))
    width, height = spec.image_size
    fx = spec.focal_factor * width
    K = [fx, 0.0, width / 2, 0.0, fx, height / 2, 0.0, 0.0, 1.0]
    cameras, gt, info = {}, {}, {}
    for im_id, vp in enumerate(spec.viewpoints):
        T_wc = camera_pose(vp, seed)
        truth.T_world_cam[im_id] = T_wc
        T_cw = np.linalg.inv(T_wc)
        cam: dict[str, Any] = {"cam_K": K}
        if spec.camera_keys in ("c2w", "both"):
            cam.update(cam_R_c2w=_flat_R(T_wc), cam_t_c2w=T_wc[:3, 3].tolist())
        if spec.camera_keys in ("w2c", "both"):
            cam.update(cam_R_w2c=_flat_R(T_cw), cam_t_w2c=T_cw[:3, 3].tolist())
        cameras[str(im_id)] = cam
        gt[str(im_id)] = [
            {"obj_id": obj_id, "cam_R_m2c": _flat_R(T_cw @ T_wm), "cam_t_m2c": (T_cw @ T_wm)[:3, 3].tolist()}
            for obj_id, T_wm in truth.objects
        ]
        if spec.old_info_keys:
            values = (("light_id", spec.light), ("carrier_id", spec.carrier), ("composition_type", spec.parts))
            info[str(im_id)] = {k: str(v) for k, v in (*values, ("viewpoint_id", vp))}
        else:
            info[str(im_id)] = {"light": spec.light, "carrier": spec.carrier, "parts": spec.parts, "viewpoint": vp}
        cv2.imwrite(str(scene_dir / "rgb" / f"{im_id:06d}.png"), np.zeros((height, width, 3), np.uint8))
    world = [{"obj_id": i, "cam_R_m2w": _flat_R(T), "cam_t_m2w": T[:3, 3].tolist()} for i, T in truth.objects]
    for name, content in (("scene_camera", cameras), ("scene_gt", gt), ("scene_gt_world", world), ("scene_info", info)):
        (scene_dir / f"{name}.json").write_text(json.dumps(content))
    return truth


def build_dimo(root: Path, specs: Iterable[SceneSpec], seed: int = 0) -> dict[str, SceneTruth]:
    """Models plus one folder per spec under ``root``; returns the truth by folder name."""
    write_models(root)
    rng = np.random.default_rng(seed)
    return {spec.folder: write_scene(root, spec, rng, seed) for spec in specs}


def edit_json(path: Path, edit: Callable[[Any], object]) -> None:
    """Load ``path``, let ``edit`` change the data in place (its return value is ignored), write it back."""
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))


def _flat_R(T: np.ndarray) -> list[float]:
    return np.asarray(T)[:3, :3].reshape(-1).tolist()
