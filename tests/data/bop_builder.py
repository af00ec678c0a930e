"""Write a small, random but seeded dataset in the BOP scenewise layout, for loader tests.

Importable by other tests: ``from tests.data.bop_builder import BopSpec, build_bop`` (the project's
pytest settings put the repository root on ``sys.path``).

What it writes (all under ``root``), T-LESS-like by default:

- ``camera_primesense.json`` (size, mean intrinsics, depth_scale 0.1);
- ``models/`` and ``models_eval/`` (or the folders named in :class:`BopSpec`): ``models_info.json``
  and ASCII PLYs: a cylinder with a continuous z symmetry, a box with discrete half-turn
  symmetries and an asymmetric tetrahedron, cycling over ``obj_ids``;
- ``test_primesense/{scene:06d}/`` for scenes 1..n: objects static in the world, a look-at camera
  per image with its own ``cam_K``, poses rounded as T-LESS rounds them (R to 6 decimals, t to
  0.01 mm), ``depth/`` uint16 PNGs (``depth_mm = png * depth_scale``), ``rgb/`` PNGs, ``mask/`` and
  ``mask_visib/`` rectangles and a ``scene_gt_info.json`` computed from them;
- ``test_targets_bop19.json``: for a random subset of each scene's images, the BOP'19 rule
  (per image and object, ``inst_count`` = instances with ``visib_fract >= 0.1``);
- ``train_pbr/{scene:06d}/`` (JPEG rgb): objects re-dropped per image (no world consistency).

The returned :class:`BuiltBop` holds the ground truth the files were written from.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
from scipy.spatial.distance import pdist
from scipy.spatial.transform import Rotation

from bop_cender.data.bop_io import save_depth, save_json, save_ply, write_image


@dataclass(frozen=True)
class BopSpec:
    """What :func:`build_bop` writes; every field has a small default."""

    seed: int = 0
    n_scenes: int = 3
    n_images: int = 7
    obj_ids: tuple[int, ...] = (1, 2, 3)
    n_instances: int = 4
    image_size: tuple[int, int] = (32, 24)  # (width, height)
    depth_scale: float = 0.1
    split_folder: str = "test_primesense"
    camera_file: str = "camera_primesense.json"
    models_dirs: tuple[str, ...] = ("models", "models_eval")
    target_fraction: float = 0.7
    with_targets: bool = True
    pbr_scenes: int = 2
    pbr_images: int = 3


@dataclass
class BuiltBop:
    """Ground truth of a built dataset.

    Attributes:
        root: the dataset root.
        T_cam_world: per test scene folder, per image id, ``(4, 4)`` as written (rounded).
        world_objects: per test scene folder, ``[(obj_id, T_world_model (4, 4))]`` (exact).
        target_images: per test scene folder, the sorted target image ids.
        targets: the entries of ``test_targets_bop19.json``.
        pbr_objects: per (pbr scene folder, image id), ``[(obj_id, T_world_model)]``.
    """

    root: Path
    spec: BopSpec
    T_cam_world: dict[str, dict[int, np.ndarray]] = field(default_factory=dict)
    world_objects: dict[str, list[tuple[int, np.ndarray]]] = field(default_factory=dict)
    target_images: dict[str, list[int]] = field(default_factory=dict)
    targets: list[dict[str, int]] = field(default_factory=list)
    pbr_objects: dict[tuple[str, int], list[tuple[int, np.ndarray]]] = field(default_factory=dict)

    @property
    def split_dir(self) -> Path:
        return self.root / self.spec.split_folder


def build_bop(root: str | Path, spec: BopSpec | None = None, **overrides: Any) -> BuiltBop:
    """Write a mini BOP dataset under ``root`` (see the module docstring); same spec, same files."""
    spec = replace(spec or BopSpec(), **overrides)
    root = Path(root)
    rng = np.random.default_rng(spec.seed)
    built = BuiltBop(root=root, spec=spec)
    width, height = spec.image_size
    save_json(
        root / spec.camera_file,
        {
            "cx": width / 2,
            "cy": height / 2,
            "depth_scale": spec.depth_scale,
            "fx": 30.0,
            "fy": 30.0,
            "height": height,
            "width": width,
        },
    )
    _write_models(root, spec)
    for scene in range(1, spec.n_scenes + 1):
        _write_test_scene(built, f"{scene:06d}", rng)
    if spec.with_targets:
        save_json(root / "test_targets_bop19.json", built.targets)
    for scene in range(spec.pbr_scenes):
        _write_pbr_scene(built, f"{scene:06d}", rng)
    return built


def edit_json(path: Path, edit: Callable[[Any], object]) -> None:
    """Load ``path``, let ``edit`` change the content in place (its return value is ignored), write it back."""
    content = json.loads(path.read_text())
    edit(content)
    path.write_text(json.dumps(content))


def round_like_tless(T: np.ndarray) -> tuple[list[float], list[float]]:
    """BOP ``(R flat, t)`` rounded as T-LESS files are: R to 6 decimals, t to 0.01 mm."""
    return [round(float(x), 6) for x in T[:3, :3].ravel()], [round(float(x), 2) for x in T[:3, 3]]


def _pose(R: np.ndarray, t: Any) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def _from_bop(R: list[float], t: list[float]) -> np.ndarray:
    return _pose(np.reshape(R, (3, 3)), t)


def _mesh(obj_id: int) -> tuple[trimesh.Trimesh, dict[str, Any]]:
    """Model ``obj_id``'s mesh (mm, centred) and its symmetry entries, by ``obj_id % 3``."""
    kind = obj_id % 3
    if kind == 1:
        return trimesh.creation.cylinder(radius=15.0, height=40.0, sections=12), {
            "symmetries_continuous": [{"axis": [0, 0, 1], "offset": [0, 0, 0]}]
        }
    if kind == 2:
        half_turns = [
            [1, 0, 0, 0, 0, -1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1],
            [-1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1],
        ]
        return trimesh.creation.box(extents=(50.0, 30.0, 20.0)), {"symmetries_discrete": half_turns}
    vertices = np.array([[-12.0, -8.0, -10.0], [14.0, -8.0, -10.0], [0.0, 16.0, -10.0], [2.0, 0.0, 10.0]])
    faces = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]])
    return trimesh.Trimesh(vertices, faces, process=False), {}


def _write_models(root: Path, spec: BopSpec) -> None:
    info = {}
    for obj_id in spec.obj_ids:
        mesh, sym = _mesh(obj_id)
        lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
        info[str(obj_id)] = {
            "diameter": float(pdist(mesh.vertices).max()),
            **{f"min_{a}": float(v) for a, v in zip("xyz", lo, strict=True)},
            **{f"size_{a}": float(v) for a, v in zip("xyz", hi - lo, strict=True)},
            **sym,
        }
        for folder in spec.models_dirs:
            save_ply(root / folder / f"obj_{obj_id:06d}.ply", mesh)
    for folder in spec.models_dirs:
        save_json(root / folder / "models_info.json", info)


def _look_at(rng: np.random.Generator) -> np.ndarray:
    """``T_cam_world`` of a camera 600-900 mm from the origin looking at it (OpenCV axes)."""
    elev, azim, dist = rng.uniform(0.3, 1.4), rng.uniform(0, 2 * math.pi), rng.uniform(600, 900)
    centre = dist * np.array([math.cos(elev) * math.cos(azim), math.cos(elev) * math.sin(azim), math.sin(elev)])
    z = -centre / np.linalg.norm(centre)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R_world_cam = np.stack([x, y, z], axis=1)
    return _pose(R_world_cam.T, -R_world_cam.T @ centre)


def _random_objects(spec: BopSpec, rng: np.random.Generator) -> list[tuple[int, np.ndarray]]:
    """Instances on a 60 mm grid (so never closer than 60 mm), ids drawn with repetition."""
    cells = rng.choice(16, size=spec.n_instances, replace=False)
    ids = rng.choice(spec.obj_ids, size=spec.n_instances)
    rots = Rotation.random(spec.n_instances, random_state=rng).as_matrix()
    return [
        (int(i), _pose(R, [60.0 * (c % 4) - 90.0, 60.0 * (c // 4) - 90.0, 20.0]))
        for i, R, c in zip(ids, rots, cells, strict=True)
    ]


def _camera_entry(T_cw: np.ndarray, spec: BopSpec, rng: np.random.Generator) -> dict[str, Any]:
    width, height = spec.image_size
    f = 30.0 + rng.uniform(-2, 2)
    K = [f, 0.0, width / 2 + rng.uniform(-2, 2), 0.0, f, height / 2 + rng.uniform(-2, 2), 0.0, 0.0, 1.0]
    R, t = round_like_tless(T_cw)
    return {
        "cam_K": [round(k, 6) for k in K],
        "cam_R_w2c": R,
        "cam_t_w2c": t,
        "depth_scale": spec.depth_scale,
        "elev": 60,
        "mode": 0,
    }


def _write_images(
    scene_dir: Path, im: int, n_gt: int, spec: BopSpec, rng: np.random.Generator, ext: str
) -> list[dict[str, Any]]:
    """rgb, depth and per-instance masks of one image; returns its scene_gt_info entries."""
    width, height = spec.image_size
    write_image(scene_dir / "rgb" / f"{im:06d}{ext}", rng.integers(0, 256, (height, width, 3), dtype=np.uint8))
    save_depth(scene_dir / "depth" / f"{im:06d}.png", rng.uniform(600, 900, (height, width)), spec.depth_scale)
    infos = []
    for gt_id in range(n_gt):
        w, h = int(rng.integers(3, width // 2)), int(rng.integers(3, height // 2))
        x, y = int(rng.integers(0, width - w)), int(rng.integers(0, height - h))
        hv = int(round(h * rng.uniform(0, 1)))
        full, visib = np.zeros((height, width), np.uint8), np.zeros((height, width), np.uint8)
        full[y : y + h, x : x + w] = 255
        visib[y : y + hv, x : x + w] = 255
        write_image(scene_dir / "mask" / f"{im:06d}_{gt_id:06d}.png", full)
        write_image(scene_dir / "mask_visib" / f"{im:06d}_{gt_id:06d}.png", visib)
        infos.append(
            {
                "bbox_obj": [x, y, w, h],
                "bbox_visib": [x, y, w, hv] if hv else [-1, -1, -1, -1],
                "px_count_all": w * h,
                "px_count_valid": w * h,
                "px_count_visib": w * hv,
                "visib_fract": hv / h,
            }
        )
    return infos


def _write_test_scene(built: BuiltBop, scene: str, rng: np.random.Generator) -> None:
    spec = built.spec
    scene_dir = built.split_dir / scene
    objects = _random_objects(spec, rng)
    cameras, gts, infos = {}, {}, {}
    built.T_cam_world[scene] = {}
    for im in range(spec.n_images):
        cameras[im] = _camera_entry(_look_at(rng), spec, rng)
        T_cw = _from_bop(cameras[im]["cam_R_w2c"], cameras[im]["cam_t_w2c"])
        built.T_cam_world[scene][im] = T_cw
        gts[im] = []
        for obj_id, T_wm in objects:
            R, t = round_like_tless(T_cw @ T_wm)
            gts[im].append({"cam_R_m2c": R, "cam_t_m2c": t, "obj_id": obj_id})
        infos[im] = _write_images(scene_dir, im, len(objects), spec, rng, ".png")
    save_json(scene_dir / "scene_camera.json", cameras)
    save_json(scene_dir / "scene_gt.json", gts)
    save_json(scene_dir / "scene_gt_info.json", infos)
    built.world_objects[scene] = objects
    n_targets = max(1, math.ceil(spec.target_fraction * spec.n_images))
    chosen = sorted(int(i) for i in rng.choice(spec.n_images, size=n_targets, replace=False))
    images = []
    for im in chosen:
        counts: dict[int, int] = {}
        for (obj_id, _), info in zip(objects, infos[im], strict=True):
            counts[obj_id] = counts.get(obj_id, 0) + (info["visib_fract"] >= 0.1)
        entries = [
            {"im_id": im, "inst_count": n, "obj_id": obj_id, "scene_id": int(scene)}
            for obj_id, n in sorted(counts.items())
            if n
        ]
        built.targets.extend(entries)
        if entries:
            images.append(im)
    built.target_images[scene] = images


def _write_pbr_scene(built: BuiltBop, scene: str, rng: np.random.Generator) -> None:
    spec = built.spec
    scene_dir = built.root / "train_pbr" / scene
    cameras, gts, infos = {}, {}, {}
    for im in range(spec.pbr_images):
        objects = _random_objects(spec, rng)
        cameras[im] = _camera_entry(_look_at(rng), spec, rng)
        T_cw = _from_bop(cameras[im]["cam_R_w2c"], cameras[im]["cam_t_w2c"])
        gts[im] = []
        for obj_id, T_wm in objects:
            R, t = round_like_tless(T_cw @ T_wm)
            gts[im].append({"cam_R_m2c": R, "cam_t_m2c": t, "obj_id": obj_id})
        infos[im] = _write_images(scene_dir, im, len(objects), spec, rng, ".jpg")
        built.pbr_objects[(scene, im)] = objects
    save_json(scene_dir / "scene_camera.json", cameras)
    save_json(scene_dir / "scene_gt.json", gts)
    save_json(scene_dir / "scene_gt_info.json", infos)
