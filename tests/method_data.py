"""A small scene for the method's tests: two asymmetric parts seen by a ring of cameras.

Built with the DIMO test builder (``tests/data/dimo_builder.py``) so that the runner and ``score`` read
it from disk like any DIMO download, and usable in memory for the stage tests.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).parent / "data"))
import dimo_builder  # noqa: E402

from bop_cender.synth.rigs import look_at  # noqa: E402

WIDTH, HEIGHT = 160, 128
VIEWPOINTS = (0, 2, 4, 6)


def l_part(a: float, b: float, c: float) -> trimesh.Trimesh:
    """An L-shaped part (no symmetry): a bar ``a x b x c`` with a post on one end, centred on its bbox."""
    bar = trimesh.creation.box(extents=(a, b, c))
    post = trimesh.creation.box(extents=(c, b, a / 2))
    post.apply_translation((a / 2 - c / 2, 0, c / 2 + a / 4))
    mesh = trimesh.util.concatenate([bar, post])
    mesh.apply_translation(-(mesh.bounds[0] + mesh.bounds[1]) / 2)
    return mesh


MESHES = {3: l_part(44.0, 14.0, 10.0), 4: l_part(36.0, 20.0, 8.0)}


def ring_camera(viewpoint: int, seed: int = 0) -> np.ndarray:
    """``T_world_cam`` of viewpoint ``viewpoint``: a ring of cameras 350 mm out, 300 mm up, looking at the origin."""
    a = 2 * np.pi * viewpoint / 8 + 0.3
    eye = np.array([350 * np.cos(a), 350 * np.sin(a), 300.0])
    return np.linalg.inv(look_at(eye, np.array([0.0, 0.0, 10.0])))


def object_poses(seed: int = 0) -> list[np.ndarray]:
    """World poses of parts 3 and 4 (random rotations, fixed places) and of the carrier 100."""
    rng = np.random.default_rng(seed)
    poses = []
    for center in ((-30.0, 5.0, 20.0), (35.0, -10.0, 20.0)):
        T = np.eye(4)
        T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
        T[:3, 3] = center
        poses.append(T)
    carrier = np.eye(4)
    carrier[2, 3] = -5.0
    return [*poses, carrier]


def build(root: Path, n_scenes: int = 1, seed: int = 0) -> Path:
    """A DIMO-layout dataset under ``root`` (split ``real``: carrier 2, composition 1, even viewpoints)."""
    dimo_builder.write_models(root, (3, 4, 100), meshes=MESHES)
    rng = np.random.default_rng(seed)
    for s in range(n_scenes):
        spec = dimo_builder.SceneSpec(
            folder=f"{s:06d}", viewpoints=VIEWPOINTS, obj_ids=(3, 4, 100), image_size=(WIDTH, HEIGHT), focal_factor=2.0
        )
        dimo_builder.write_scene(root, spec, rng, seed, camera_pose=ring_camera, object_poses=object_poses(seed + s))
    return root


#: Binarisation threshold of the oracle curvature of the box parts (with curvature scale 1; see tests/pose/conftest.py).
BOX_T_B = 0.5


def gt_of(scene, obj_id: int):
    """The scene's GT object of ``obj_id`` (the test scene holds one of each)."""
    return next(g for g in scene.gt if g.obj_id == obj_id)


def perturb(T: np.ndarray, angle_deg: float, shift_mm: float, axis=(0.3, 0.5, 0.8)) -> np.ndarray:
    """``T (4, 4)`` rotated by ``angle_deg`` about ``axis`` (model side) and shifted by ``shift_mm``."""
    axis = np.asarray(axis) / np.linalg.norm(axis)
    out = T.copy()
    out[:3, :3] = Rotation.from_rotvec(np.radians(angle_deg) * axis).as_matrix() @ T[:3, :3]
    out[:3, 3] += shift_mm * np.array([0.6, -0.8, 0.0])
    return out


def mini_scene(root: Path):
    """``(dataset, scene, meshes, oracle maps, cameras, distance maps)`` of the method's test scene, built under
    ``root``. The fixture's parts are boxes: every edge is a crease or a silhouette, so the curvature scale 1 and
    :data:`BOX_T_B` keep all of them (the defaults, 4 and 0.75, are tuned for thin curved parts, where they thin these
    edges at this fixture's 1.25 mm per pixel)."""
    import torch

    from bop_cender.data.dimo import open_dimo
    from bop_cender.meshes import MeshCache
    from bop_cender.net.targets import TargetConfig, scene_targets
    from bop_cender.pose.cost import distance_maps
    from bop_cender.pose.types import SceneCameras

    ds = open_dimo(build(root), "real")
    scene = ds.scene(ds.scene_keys[0])
    meshes = MeshCache(ds.models)
    maps = scene_targets(scene, ds.models, meshes, TargetConfig(curvature_scale=1.0))
    cams = SceneCameras(np.stack([v.K for v in scene.views]), np.stack([v.T_cam_world for v in scene.views]),
                        HEIGHT, WIDTH)  # fmt: skip
    dist = torch.as_tensor(distance_maps(maps.curvature.numpy() > BOX_T_B))
    return ds, scene, meshes, maps, cams, dist


def pose_config(*settings: str, t_b: float | None = None):
    """A stage-3 config at this fixture's :data:`BOX_T_B` (or ``t_b``) with ``path=value`` settings below ``poses``
    applied (``"sweeps.passes=2"``, ``"refine.nelder_mead.maxfev=40"``), as ``run --set`` applies them."""
    from bop_cender.pose.config import PoseConfig
    from bop_cender.settings import apply_setting

    config = PoseConfig(t_b=BOX_T_B if t_b is None else t_b)
    for item in settings:
        config = apply_setting(config, item)
    return config


def pose_context(mini, config=None, **kwargs):
    """The stage-3 context of the :func:`mini_scene` ``mini`` (its oracle curvature, cameras, meshes and model centres)
    under ``config`` (default :func:`pose_config`), curvature scale 1 as the fixture's targets; ``kwargs`` as
    :func:`~bop_cender.pose.context.scene_context`'s."""
    from bop_cender.pose.context import scene_context

    ds, scene, meshes, maps, cams, dist = mini
    config = pose_config() if config is None else config
    return scene_context(maps.curvature, cams, meshes, lambda i: ds.models[i].center, config,
                         **{"curvature_scale": 1.0, **kwargs})  # fmt: skip


def target_parts(ds, scene) -> dict[int, np.ndarray]:
    """``obj_id -> T_world_model (4, 4)`` of the scene's target parts (the carriers left out)."""
    return {g.obj_id: g.T_world_model for g in scene.gt if ds.models[g.obj_id].is_target}


def full_scene_cost(meshes, poses: dict[int, np.ndarray], cams, edges, dist) -> float:
    """The default backend's scene cost of the parts at ``poses`` (``obj_id -> T_world_model``), at this fixture's
    edge threshold (:data:`BOX_T_B`: its curvature scale is 1)."""
    import torch

    from bop_cender.pose.backend import backend_named

    ids = sorted(poses)
    T_cm = np.einsum("vij,mjk->vmik", cams.T_cam_world, np.stack([poses[i] for i in ids]))
    Ks = torch.as_tensor(cams.Ks, dtype=torch.float32)
    return backend_named("auto").scene_cost(
        [meshes(i) for i in ids], torch.as_tensor(T_cm, dtype=torch.float32), Ks, edges, dist, BOX_T_B
    )


#: Cheap stage-3 settings for runner tests: the rows are not precise, but every run with them must give the same rows.
CHEAP = ["poses.candidates.n=48", "poses.candidates.top_k=2", "poses.refine.nelder_mead.maxfev=40"]


def cheap_request(root: Path, out: Path, **kw):
    """A :class:`~bop_cender.runner.RunRequest` of the oracle on ``root``'s ``real`` split (a :func:`build` set) with
    :data:`CHEAP` settings and deterministic times; ``kw`` replaces any field."""
    from bop_cender.method import CenDerNetConfig
    from bop_cender.runner import RunRequest

    base = dict(dataset="dimo", data_root=str(root), split="real", out=out, deterministic_time=True,
                config=CenDerNetConfig.for_dataset("dimo").with_settings(CHEAP))  # fmt: skip
    base.update(kw)
    return RunRequest(**base)
