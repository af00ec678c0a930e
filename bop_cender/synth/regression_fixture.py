"""A small, seeded T-LESS-layout dataset with ray-cast test depth, and results with known perturbations.

Used by the regression check (``scripts/regression.py``), the scoring benchmark
(``scripts/bench_score.py``) and the scoring tests. Self-contained (it does not import ``tests/``)
and deterministic: same spec, same files.

The dataset (:func:`build_fixture`) is T-LESS as the toolkit knows it: ``test_primesense/`` scenes
of 720x540 images, ``camera_primesense.json``, ``models_cad/`` and ``models_eval/`` (same meshes),
``test_targets_bop19.json`` (the 0.1 visibility rule on a subset of the images). Each scene is a
table with objects on it: a cylinder with a continuous symmetry and a half-turn (obj 1), a box with
three half-turns (obj 2), an asymmetric wedge (obj 3), some repeated, and a plate (not annotated)
hovering over the last one. Test depth is ray-cast with Embree (:func:`sensor_depth`, independent of our
rasteriser, so the toolkit anchor computed on the fixture stays valid when the renderer changes), with
sensor noise and dropouts (0 = missing), stored as uint16 x 0.1 mm; ``visib_fract`` = visible pixels /
whole-silhouette pixels, from our renderer.

The results (:func:`regression_estimates`) straddle the thresholds on purpose: exact poses,
translations of 4.5 % and 5.5 % of the diameter (MSSD just inside / outside 5 %), 29 %, rotations
about the continuous symmetry axis or by a discrete symmetry (must score as GT), small rotations,
poses far away (early-outs), duplicates, estimates of non-target objects and of non-target images.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.distance import pdist
from scipy.spatial.transform import Rotation

from bop_cender.data.bop_io import save_depth, save_json, save_ply
from bop_cender.data.layout import MIN_VISIB_FRACT, SCENE_CAMERA, SCENE_GT, SCENE_GT_INFO, TARGETS_FILE
from bop_cender.render.mesh import prepare_mesh
from bop_cender.results.bop_csv import BopEstimate
from bop_cender.visibility import pile_visibility

SPLIT_FOLDER = "test_primesense"
#: The non-annotated occluders: the table everything stands on, and the plate over the last object.
TABLE_EXTENTS = (700.0, 700.0, 10.0)
PLATE_EXTENTS = (150.0, 150.0, 4.0)
OCCLUDER_EXTENTS = (TABLE_EXTENTS, PLATE_EXTENTS)
DEPTH_SCALE = 0.1


@dataclass(frozen=True)
class FixtureSpec:
    """What :func:`build_fixture` writes.

    Attributes:
        seed: everything random derives from it.
        n_scenes, n_images: scenes and images per scene.
        objects: obj_ids placed in every scene (repeats give several instances).
        image_size: (width, height); T-LESS's 720x540 by default (intrinsics scale with the width).
        min_vertices: meshes are subdivided until they have at least this many vertices (T-LESS
            ``models_eval`` meshes have a few thousand; 0 keeps the coarse meshes, a few dozen to hundreds).
        target_fraction: fraction of each scene's images that are targets.
        dropout: fraction of depth pixels set to 0 (missing).
        extra_models: object ids with a model but no instance (their estimates are never targets).
        occluder: a plate (not annotated) hovering over the last object: it hides it mostly or wholly.
    """

    seed: int = 20240601
    n_scenes: int = 2
    n_images: int = 4
    objects: tuple[int, ...] = (1, 2, 3, 1, 2, 1)
    image_size: tuple[int, int] = (720, 540)
    min_vertices: int = 0
    target_fraction: float = 0.75
    dropout: float = 0.02
    extra_models: tuple[int, ...] = (4,)
    occluder: bool = True


@dataclass
class BuiltFixture:
    """What was written.

    Attributes:
        gt: per (scene_int, im_id), ``[(gt_id, obj_id, T_cam_model (4, 4))]``.
        visib: per (scene_int, im_id), the visible fraction of each gt_id.
        K, T_cam_world: per (scene_int, im_id), ``(3, 3)`` and ``(4, 4)``.
        world: per scene_int, ``[(obj_id, T_world_model)]`` of the instances (gt_id order).
        occluders: per scene_int, ``[("table" | "plate", T_world_model)]`` (not annotated).
        targets: the targets file's entries. models: ``models_info.json`` entries by obj_id.
    """

    root: Path
    spec: FixtureSpec
    gt: dict[tuple[int, int], list[tuple[int, int, np.ndarray]]] = field(default_factory=dict)
    visib: dict[tuple[int, int], list[float]] = field(default_factory=dict)
    K: dict[tuple[int, int], np.ndarray] = field(default_factory=dict)
    T_cam_world: dict[tuple[int, int], np.ndarray] = field(default_factory=dict)
    world: dict[int, list[tuple[int, np.ndarray]]] = field(default_factory=dict)
    occluders: dict[int, list[tuple[str, np.ndarray]]] = field(default_factory=dict)
    targets: list[dict[str, int]] = field(default_factory=list)
    models: dict[int, dict] = field(default_factory=dict)

    @property
    def target_images(self) -> list[tuple[int, int]]:
        return sorted({(t["scene_id"], t["im_id"]) for t in self.targets})


def build_fixture(root: str | Path, spec: FixtureSpec | None = None) -> BuiltFixture:
    """Write the fixture dataset under ``root`` (see the module docstring) and return its ground truth."""
    spec = spec or FixtureSpec()
    root = Path(root)
    rng = np.random.default_rng(spec.seed)
    built = BuiltFixture(root, spec)
    width, height = spec.image_size
    save_json(
        root / "camera_primesense.json",
        {"cx": width / 2, "cy": height / 2, "depth_scale": DEPTH_SCALE, "fx": 1075.0 * width / 720,
         "fy": 1073.0 * width / 720, "height": height, "width": width},
    )  # fmt: skip
    obj_ids = sorted(set(spec.objects) | set(spec.extra_models))
    meshes = {obj_id: fixture_mesh(obj_id, spec.min_vertices) for obj_id in obj_ids}
    for obj_id, (mesh, sym) in meshes.items():
        for folder in ("models_cad", "models_eval"):
            save_ply(root / folder / f"obj_{obj_id:06d}.ply", mesh)
        lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
        built.models[obj_id] = {
            "diameter": float(pdist(mesh.vertices).max()),
            **{f"min_{a}": float(v) for a, v in zip("xyz", lo, strict=True)},
            **{f"size_{a}": float(v) for a, v in zip("xyz", hi - lo, strict=True)},
            **sym,
        }
    for folder in ("models_cad", "models_eval"):
        save_json(root / folder / "models_info.json", {str(k): v for k, v in built.models.items()})
    render_meshes = {obj_id: prepare_mesh(m) for obj_id, (m, _) in meshes.items()}
    plate = prepare_mesh(trimesh.creation.box(extents=PLATE_EXTENTS))
    for scene in range(1, spec.n_scenes + 1):
        _write_scene(built, scene, rng, render_meshes, {o: m for o, (m, _) in meshes.items()}, plate)
    save_json(root / TARGETS_FILE, built.targets)
    return built


def fixture_mesh(obj_id: int, min_vertices: int = 0) -> tuple[trimesh.Trimesh, dict]:
    """Model ``obj_id`` (1 cylinder, 2 box, 3 wedge; others cycle) in mm, and its ``models_info`` symmetries."""
    kind = (obj_id - 1) % 3
    if kind == 0:
        mesh = trimesh.creation.cylinder(radius=30.0, height=80.0, sections=24)
        sym = {
            "symmetries_continuous": [{"axis": [0, 0, 1], "offset": [0, 0, 0]}],
            "symmetries_discrete": [[1, 0, 0, 0, 0, -1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1]],
        }
    elif kind == 1:
        mesh = trimesh.creation.box(extents=(50.0, 30.0, 20.0))
        sym = {"symmetries_discrete": [
            [1, 0, 0, 0, 0, -1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1],
            [-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1],
            [-1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1],
        ]}  # fmt: skip
    else:
        vertices = np.array(
            [[-30, -20, -15], [30, -20, -15], [30, 20, -15], [-30, 20, -15], [-30, -20, 15], [-30, 20, 15]], float
        )
        mesh = trimesh.convex.convex_hull(vertices)
        sym = {}
    while len(mesh.vertices) < min_vertices:
        mesh = mesh.subdivide()
    return trimesh.Trimesh(mesh.vertices, mesh.faces, process=False), sym


def _look_at(rng: np.random.Generator, target: np.ndarray) -> np.ndarray:
    """``T_cam_world`` of a camera 650-900 mm from ``target`` at 35-70 degrees elevation (OpenCV axes)."""
    elev, azim, dist = rng.uniform(0.6, 1.2), rng.uniform(0, 2 * math.pi), rng.uniform(650, 900)
    eye = target + dist * np.array([math.cos(elev) * math.cos(azim), math.cos(elev) * math.sin(azim), math.sin(elev)])
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: camera axes in world
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, -R @ eye
    return T


def _write_scene(built: BuiltFixture, scene: int, rng: np.random.Generator, render_meshes, meshes, plate) -> None:
    spec = built.spec
    width, height = spec.image_size
    scene_dir = built.root / SPLIT_FOLDER / f"{scene:06d}"
    cells = rng.permutation(9)[: len(spec.objects)]
    T_world = []
    for obj_id, cell in zip(spec.objects, cells, strict=True):
        R = Rotation.random(random_state=rng).as_matrix()
        lift = -float((meshes[obj_id].vertices @ R.T)[:, 2].min())
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = [75.0 * (cell % 3 - 1) + rng.uniform(-8, 8), 75.0 * (cell // 3 - 1) + rng.uniform(-8, 8), lift + 0.5]
        T_world.append(T)
    T_table = np.eye(4)
    T_table[2, 3] = -5.0
    occluders = []  # render meshes of the occluders that can hide objects (the table cannot)
    T_occluders = [T_table]
    if spec.occluder:  # a plate 15 mm above the last object, hiding it from most viewpoints
        T_plate = np.eye(4)
        top = float((meshes[spec.objects[-1]].vertices @ T_world[-1][:3, :3].T)[:, 2].max()) + T_world[-1][2, 3]
        T_plate[:3, 3] = [T_world[-1][0, 3], T_world[-1][1, 3], top + 15.0]
        occluders.append(plate)
        T_occluders.append(T_plate)
    T_cw = np.stack([_look_at(rng, np.array([0.0, 0.0, 20.0])) for _ in range(spec.n_images)])  # (V, 4, 4)
    Ks = np.stack([_intrinsics(rng, width, height) for _ in range(spec.n_images)])
    T_cm = T_cw[:, None] @ np.stack(T_world)[None]  # (V, M, 4, 4)
    objs = [render_meshes[o] for o in spec.objects]
    T_occ = np.stack([T_cw @ T for T in T_occluders], axis=1)  # (V, occluders, 4, 4)
    world = [meshes[o].copy().apply_transform(T) for o, T in zip(spec.objects, T_world, strict=True)]
    world += [
        trimesh.creation.box(extents=e).apply_transform(T) for e, T in zip(OCCLUDER_EXTENTS, T_occluders, strict=False)
    ]
    depth = sensor_depth(trimesh.util.concatenate(world), T_cw, Ks, height, width)
    depth = depth + rng.normal(0.0, 0.4, depth.shape) * (depth > 0)
    depth[rng.random(depth.shape) < spec.dropout] = 0.0
    pile = np.concatenate([T_cm, T_occ[:, 1:]], axis=1)  # the objects and the plate (the table hides nothing)
    counts = pile_visibility([*objs, *occluders], pile, Ks, height, width, counted=len(objs))
    visible, total, fract = counts.visible, counts.total, counts.fract  # (V, M)
    cameras, gts, infos = {}, {}, {}
    for v in range(spec.n_images):
        cameras[v] = {"cam_K": Ks[v].ravel().tolist(), "cam_R_w2c": T_cw[v, :3, :3].ravel().tolist(),
                      "cam_t_w2c": T_cw[v, :3, 3].tolist(), "depth_scale": DEPTH_SCALE, "elev": 45, "mode": 0}  # fmt: skip
        gts[v] = [
            {"cam_R_m2c": T_cm[v, m, :3, :3].ravel().tolist(), "cam_t_m2c": T_cm[v, m, :3, 3].tolist(), "obj_id": o}
            for m, o in enumerate(spec.objects)
        ]
        fracts = [float(fract[v, m]) for m in range(len(objs))]
        infos[v] = [
            {"px_count_all": int(total[v, m]), "px_count_visib": int(visible[v, m]), "visib_fract": fracts[m]}
            for m in range(len(objs))
        ]
        save_depth(scene_dir / "depth" / f"{v:06d}.png", depth[v], DEPTH_SCALE)
        built.gt[(scene, v)] = [(m, o, T_cm[v, m]) for m, o in enumerate(spec.objects)]
        built.visib[(scene, v)] = fracts
        built.K[(scene, v)] = Ks[v]
        built.T_cam_world[(scene, v)] = T_cw[v]
    built.world[scene] = list(zip(spec.objects, T_world, strict=True))
    built.occluders[scene] = list(zip(("table", "plate"), T_occluders, strict=False))
    save_json(scene_dir / SCENE_CAMERA, cameras)
    save_json(scene_dir / SCENE_GT, gts)
    save_json(scene_dir / SCENE_GT_INFO, infos)
    n_targets = max(1, math.ceil(spec.target_fraction * spec.n_images))
    for v in sorted(rng.choice(spec.n_images, size=n_targets, replace=False).tolist()):
        counts: dict[int, int] = {}
        for m, o in enumerate(spec.objects):
            if built.visib[(scene, v)][m] >= MIN_VISIB_FRACT:
                counts[o] = counts.get(o, 0) + 1
        built.targets.extend({"im_id": v, "inst_count": n, "obj_id": o, "scene_id": scene} for o, n in counts.items())


def sensor_depth(scene: trimesh.Trimesh, T_cam_world: np.ndarray, K: np.ndarray, height: int, width: int) -> np.ndarray:
    """The "sensor": depth ``(V, H, W)`` (mm, 0 = no hit) by ray casting ``scene`` (world frame) with Embree.

    Independent of our rasteriser on purpose, so that the fixture (and the toolkit anchor computed on it)
    stays valid when the renderer changes: one ray per pixel through its centre (u + 0.5, v + 0.5), depth =
    camera z of the first hit.

    Raises:
        RuntimeError: Embree (``embreex``, in the ``dev`` extra) is not installed: trimesh's slower fallback
            intersects in another precision, so the committed regression numbers would not be reproduced.
    """
    if not trimesh.ray.has_embree:
        raise RuntimeError("the regression fixture needs Embree ray casting: pip install embreex (the dev extra)")
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    intersector = RayMeshIntersector(scene)
    v, u = np.mgrid[0:height, 0:width]
    pix = np.stack([u.ravel() + 0.5, v.ravel() + 0.5, np.ones(u.size)])  # (3, H*W)
    out = np.zeros((len(T_cam_world), height, width))
    for k, (T_cw, K_k) in enumerate(zip(T_cam_world, K, strict=True)):
        R_wc = T_cw[:3, :3].T
        eye = -R_wc @ T_cw[:3, 3]
        dirs = (R_wc @ np.linalg.solve(K_k, pix)).T
        hits, rays, _ = intersector.intersects_location(np.broadcast_to(eye, dirs.shape), dirs, multiple_hits=False)
        z = (hits - eye) @ T_cw[2, :3]  # camera z of each hit
        out[k].reshape(-1)[rays] = z
    return out


def _intrinsics(rng: np.random.Generator, width: int, height: int) -> np.ndarray:
    """T-LESS Primesense-like intrinsics (fx ~ 1075 px at 720 px wide, scaled with the width) with a per-image
    principal point, as T-LESS crops have."""
    scale = width / 720.0
    return np.array(
        [[scale * (1075.65 + rng.uniform(-2, 2)), 0.0, width / 2 + scale * rng.uniform(-8, 8)],
         [0.0, scale * (1073.90 + rng.uniform(-2, 2)), height / 2 + scale * rng.uniform(-8, 8)],
         [0.0, 0.0, 1.0]]
    )  # fmt: skip


#: Perturbations applied in turn to the GT instances of the target images (see regression_estimates).
PERTURBATIONS = ("exact", "t_4.5%", "t_5.5%", "t_29%", "symmetric", "rot_5deg", "far", "t_12%_z")


def perturb(kind: str, T: np.ndarray, info: dict, rng: np.random.Generator) -> np.ndarray:
    """The GT pose ``T (4, 4)`` moved by one of :data:`PERTURBATIONS` (fractions of the diameter)."""
    out = T.copy()
    diameter = info["diameter"]
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    if kind.startswith("t_") and kind.endswith("%"):
        out[:3, 3] += float(kind[2:-1]) / 100.0 * diameter * direction
    elif kind == "t_12%_z":  # along the camera axis: small in the image, large in 3D
        out[2, 3] += 0.12 * diameter
    elif kind == "symmetric":
        if info.get("symmetries_continuous"):
            axis = np.asarray(info["symmetries_continuous"][0]["axis"], float)
            R_s = Rotation.from_rotvec(rng.uniform(0.3, 6.0) * axis / np.linalg.norm(axis)).as_matrix()
        elif info.get("symmetries_discrete"):
            S = np.asarray(info["symmetries_discrete"][int(rng.integers(len(info["symmetries_discrete"])))], float)
            R_s = S.reshape(4, 4)[:3, :3]
        else:
            R_s = Rotation.from_rotvec(np.radians(1.0) * direction).as_matrix()
        out[:3, :3] = T[:3, :3] @ R_s
    elif kind == "rot_5deg":
        out[:3, :3] = Rotation.from_rotvec(np.radians(5.0) * direction).as_matrix() @ T[:3, :3]
    elif kind == "far":
        out[:3, 3] += 2.0 * diameter * direction
    elif kind != "exact":
        raise ValueError(f"unknown perturbation {kind!r}")
    return out


def regression_estimates(built: BuiltFixture, seed: int = 1) -> list[BopEstimate]:
    """Results for the fixture: every perturbation, duplicates, non-target objects and images (see module doc)."""
    rng = np.random.default_rng(seed)
    rows: list[BopEstimate] = []
    targets = {(t["scene_id"], t["im_id"]) for t in built.targets}
    k = 0
    for key in sorted(built.gt):
        scene, im = key
        time_s = 0.25 + 0.01 * im
        if key not in targets:  # a non-target image: ignored by the evaluation
            _, o, T = built.gt[key][0]
            rows.append(_row(scene, im, o, 0.9, T, time_s))
            continue
        for _gt_id, obj_id, T in built.gt[key]:
            kind = PERTURBATIONS[k % len(PERTURBATIONS)]
            k += 1
            score = round(float(rng.uniform(0.2, 1.0)), 3)
            rows.append(_row(scene, im, obj_id, score, perturb(kind, T, built.models[obj_id], rng), time_s))
            if k % 5 == 0:  # a duplicate with a lower score: beyond top-n or unmatched
                rows.append(
                    _row(scene, im, obj_id, score / 2, perturb("rot_5deg", T, built.models[obj_id], rng), time_s)
                )
        absent = [o for o in built.models if o not in {g[1] for g in built.gt[key]}]
        if absent:  # an object that is not in the image: not a target, ignored
            rows.append(_row(scene, im, absent[0], 0.99, built.gt[key][0][2], time_s))
    return rows


def bench_estimates(built: BuiltFixture, per_instance: int = 1, seed: int = 2) -> list[BopEstimate]:
    """``per_instance`` estimates near each target instance (visib_fract >= 0.1) of the target images.

    Each is 1-4 degrees and 1-6 mm from its GT, so no early-out skips its work; with ``per_instance = 1``
    every estimate is within its target's ``inst_count`` and evaluated.
    """
    rng = np.random.default_rng(seed)
    rows = []
    targets = {(t["scene_id"], t["im_id"]) for t in built.targets}
    for key in sorted(targets):
        scene, im = key
        for gt_id, obj_id, T in built.gt[key]:
            if built.visib[key][gt_id] < MIN_VISIB_FRACT:
                continue
            for _ in range(per_instance):
                out = T.copy()
                axis = rng.normal(size=3)
                angle = np.radians(rng.uniform(1, 4))
                out[:3, :3] = Rotation.from_rotvec(angle * axis / np.linalg.norm(axis)).as_matrix() @ T[:3, :3]
                out[:3, 3] += rng.normal(size=3) * rng.uniform(1, 6) / math.sqrt(3)
                rows.append(_row(scene, im, obj_id, round(float(rng.uniform(0, 1)), 4), out, 0.5))
    return rows


def _row(scene: int, im: int, obj_id: int, score: float, T: np.ndarray, time_s: float) -> BopEstimate:
    return BopEstimate(scene, im, obj_id, score, T[:3, :3], T[:3, 3], time_s)
