"""The stage-3 tests' scene: the method's small two-part scene with its oracle curvature and distance maps."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).parents[1]))
import method_data  # noqa: E402

from bop_cender.data.dimo import open_dimo  # noqa: E402
from bop_cender.meshes import MeshCache  # noqa: E402
from bop_cender.net.targets import TargetConfig, scene_targets  # noqa: E402
from bop_cender.pose.cost import distance_maps  # noqa: E402
from bop_cender.pose.optimize import SceneCameras  # noqa: E402


@pytest.fixture(scope="module")
def mini(tmp_path_factory):
    """``(dataset, scene, meshes, oracle maps, cameras, distance maps)`` of the method's test scene."""
    root = method_data.build(tmp_path_factory.mktemp("mini") / "dimo")
    ds = open_dimo(root, "real")
    scene = ds.scene(ds.scene_keys[0])
    meshes = MeshCache(ds.models)
    # The fixture's parts are boxes: every edge is a crease or a silhouette, so the curvature scale 1 and
    # t_b 0.5 keep all of them (the defaults, 4 and 0.75, are tuned for thin curved parts, where they
    # thin these edges at this fixture's 1.25 mm per pixel).
    maps = scene_targets(scene, ds.models, meshes, TargetConfig(curvature_scale=1.0))
    cams = SceneCameras(np.stack([v.K for v in scene.views]), np.stack([v.T_cam_world for v in scene.views]),
                        method_data.HEIGHT, method_data.WIDTH)  # fmt: skip
    dist = torch.as_tensor(distance_maps(maps.curvature.numpy() > method_data.BOX_T_B))
    return ds, scene, meshes, maps, cams, dist
