"""Test data for the scorer: small regression fixtures, estimate rows, and the same scene in DIMO layout.

Importable as ``tests.eval.scoring_data`` (the repository root is on ``sys.path`` in the pytest settings).
The BOP fixture is :mod:`bop_cender.synth.regression_fixture` at 240x180 (intrinsics scaled with it);
:func:`write_dimo_copy` writes the same objects, cameras and occluders as a DIMO scene, with the table
and the plate as carriers (ids 100, 101), independently of the project's writers (plain json).
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import trimesh

from bop_cender.data.layout import MIN_VISIB_FRACT
from bop_cender.results.bop_csv import BopEstimate
from bop_cender.synth.regression_fixture import PLATE_EXTENTS, TABLE_EXTENTS, BuiltFixture, FixtureSpec, perturb

SMALL = FixtureSpec(seed=5, n_scenes=2, n_images=3, image_size=(240, 180), target_fraction=0.6)
CARRIERS = {100: TABLE_EXTENTS, 101: PLATE_EXTENTS}


def row(scene: int, im: int, obj: int, score: float, T: np.ndarray, time_s: float = -1.0) -> BopEstimate:
    return BopEstimate(scene, im, obj, score, T[:3, :3], T[:3, 3], time_s)


def target_instances(built: BuiltFixture) -> list[tuple[int, int, int, int, np.ndarray]]:
    """``(scene, im, gt_id, obj_id, T_cam_model)`` of every instance with visib_fract >= 0.1 in a target image."""
    images = sorted({(t["scene_id"], t["im_id"]) for t in built.targets})
    return [
        (s, i, g, o, T) for s, i in images for g, o, T in built.gt[(s, i)] if built.visib[(s, i)][g] >= MIN_VISIB_FRACT
    ]


def gt_rows(built: BuiltFixture, kinds: dict[int, str] | None = None, seed: int = 0) -> list[BopEstimate]:
    """One estimate per target instance: its GT pose, or ``perturb(kinds[obj_id], ...)`` (score 1)."""
    rng = np.random.default_rng(seed)
    out = []
    for s, i, _g, o, T in target_instances(built):
        pose = perturb(kinds[o], T, built.models[o], rng) if kinds and o in kinds else T
        out.append(row(s, i, o, 1.0, pose, 0.5))
    return out


def write_dimo_copy(built: BuiltFixture, root: Path) -> Path:
    """The fixture's first scene as DIMO ``real_jaigo/000000`` (c2w cameras, scene_gt_world, scene_info).

    Viewpoints 0, 2, 4, ... (the paper's selection keeps them), carrier 2, composition 1; no depth and no
    scene_gt_info, as DIMO. Returns the DIMO root.
    """
    scene = 1
    models = root / "models"
    models.mkdir(parents=True, exist_ok=True)
    info = {}
    src = built.root / "models_eval"
    for obj_id, entry in built.models.items():
        (models / f"obj_{obj_id:06d}.ply").write_bytes((src / f"obj_{obj_id:06d}.ply").read_bytes())
        info[str(obj_id)] = entry
    for obj_id, extents in CARRIERS.items():
        mesh = trimesh.creation.box(extents=extents)
        (models / f"obj_{obj_id:06d}.ply").write_bytes(trimesh.exchange.ply.export_ply(mesh, encoding="ascii"))
        info[str(obj_id)] = {"diameter": float(np.linalg.norm(extents)),
                             **{f"min_{a}": -e / 2 for a, e in zip("xyz", extents, strict=True)},
                             **{f"size_{a}": e for a, e in zip("xyz", extents, strict=True)}}  # fmt: skip
    (models / "models_info.json").write_text(json.dumps(info))
    world = list(built.world[scene]) + [(100 if n == "table" else 101, T) for n, T in built.occluders[scene]]
    scene_dir = root / "real_jaigo" / "000000"
    (scene_dir / "rgb").mkdir(parents=True, exist_ok=True)
    width, height = built.spec.image_size
    cameras, gts, infos = {}, {}, {}
    for im in range(built.spec.n_images):
        T_cw = built.T_cam_world[(scene, im)]
        T_wc = np.linalg.inv(T_cw)
        cameras[str(im)] = {"cam_K": built.K[(scene, im)].ravel().tolist(),
                            "cam_R_c2w": T_wc[:3, :3].ravel().tolist(), "cam_t_c2w": T_wc[:3, 3].tolist()}  # fmt: skip
        gts[str(im)] = [
            {"obj_id": o, "cam_R_m2c": (T_cw @ T)[:3, :3].ravel().tolist(), "cam_t_m2c": (T_cw @ T)[:3, 3].tolist()}
            for o, T in world
        ]
        infos[str(im)] = {"light": 0, "carrier": 2, "parts": 1, "viewpoint": 2 * im}
        cv2.imwrite(str(scene_dir / "rgb" / f"{im:06d}.png"), np.zeros((height, width, 3), np.uint8))
    gt_world = [
        {"obj_id": o, "cam_R_m2w": T[:3, :3].ravel().tolist(), "cam_t_m2w": T[:3, 3].tolist()} for o, T in world
    ]
    for name, content in (("scene_camera", cameras), ("scene_gt", gts), ("scene_gt_world", gt_world),
                          ("scene_info", infos)):  # fmt: skip
        (scene_dir / f"{name}.json").write_text(json.dumps(content))
    return root
