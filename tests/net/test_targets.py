"""GT heatmaps: blob size and place, carriers and hidden surfaces left out, the oracle's degradations."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).parents[1]))
import method_data  # noqa: E402

from bop_cender.data.dimo import open_dimo  # noqa: E402
from bop_cender.data.types import GtObject  # noqa: E402
from bop_cender.meshes import MeshCache  # noqa: E402
from bop_cender.net.heatmaps import Heatmaps  # noqa: E402
from bop_cender.net.oracle import Degradation, OraclePredictor  # noqa: E402
from bop_cender.net.targets import TargetConfig, blob_sigma, scene_targets  # noqa: E402
from bop_cender.render.curvature import curvature  # noqa: E402
from bop_cender.render.rasterizer import render_scene  # noqa: E402


@pytest.fixture(scope="module")
def mini(tmp_path_factory):
    root = method_data.build(tmp_path_factory.mktemp("targets") / "dimo")
    ds = open_dimo(root, "real")
    return ds, ds.scene(ds.scene_keys[0]), MeshCache(ds.models)


def test_sigma_formula():
    # s_e * mean extent * 100 / distance: 0.5 * 40 * 100 / 500 = 4 px
    assert blob_sigma(0.5, np.array([20.0, 40.0, 60.0]), 500.0) == pytest.approx(4.0)
    assert blob_sigma(1.25, np.array([30.0, 30.0, 30.0]), np.array([750.0]))[0] == pytest.approx(5.0)


def test_blob_peak_at_the_projected_centre(mini):
    ds, scene, meshes = mini
    maps = scene_targets(scene, ds.models, meshes, TargetConfig(s_e=0.5))
    g = next(g for g in scene.gt if g.obj_id == 3)
    model = ds.models[3]
    c_world = g.T_world_model[:3, :3] @ model.center + g.T_world_model[:3, 3]
    for i, view in enumerate(scene.views):
        p = view.T_cam_world[:3, :3] @ c_world + view.T_cam_world[:3, 3]
        x, y = (view.K @ p)[:2] / p[2]
        u, v = int(np.floor(x)), int(np.floor(y))
        sigma = 0.5 * np.mean(model.bbox_size) * 100 / np.linalg.norm(p)
        expected = np.exp(-((u + 0.5 - x) ** 2 + (v + 0.5 - y) ** 2) / (2 * sigma**2))
        assert float(maps.center[i, 0, v, u]) == pytest.approx(expected, rel=1e-5)
        # the local maximum is that pixel (the other part's blob is far away)
        window = maps.center[i, 0, v - 2 : v + 3, u - 2 : u + 3]
        assert float(window.max()) == pytest.approx(float(maps.center[i, 0, v, u]))
    assert maps.center.shape == (4, 1, method_data.HEIGHT, method_data.WIDTH)
    assert float(maps.center.max()) <= 1.0 and float(maps.curvature.max()) <= 1.0


def test_carriers_draw_no_curvature(mini):
    ds, scene, meshes = mini
    maps = scene_targets(scene, ds.models, meshes, TargetConfig())
    T = np.stack([[v.T_cam_world @ g.T_world_model for g in scene.gt] for v in scene.views])
    r = render_scene([meshes(g.obj_id) for g in scene.gt], T, np.stack([v.K for v in scene.views]),
                     method_data.HEIGHT, method_data.WIDTH)  # fmt: skip
    carrier = [k for k, g in enumerate(scene.gt) if g.obj_id == 100][0]
    on_carrier = r.instance == carrier
    # carrier pixels away from any target (2 px margin for the target's own silhouette ring)
    target = (r.instance >= 0) & ~on_carrier
    near_target = torch.nn.functional.max_pool2d(target[:, None].float(), 5, 1, 2)[:, 0] > 0
    assert on_carrier.any()
    assert float(maps.curvature[on_carrier & ~near_target].abs().max()) == 0.0
    # with every pixel a target (no masking), the carrier's own silhouette would be there
    assert float(curvature(r.normals)[on_carrier & ~near_target].max()) > 1.0
    assert float(maps.curvature[target].max()) == 1.0


def test_hidden_objects_get_no_curvature_and_no_blob(mini):
    ds, scene, meshes = mini
    hidden = []
    for g in scene.gt:
        if g.obj_id == 3:
            T = g.T_world_model.copy()
            T[2, 3] = -40.0  # under the carrier plate (z -10 .. 0): no camera sees it
            g = GtObject(g.obj_id, T, g.gt_ids)
        hidden.append(g)
    maps = scene_targets(replace(scene, gt=tuple(hidden)), ds.models, meshes, TargetConfig())
    only4 = scene_targets(replace(scene, gt=tuple(g for g in hidden if g.obj_id != 3)), ds.models, meshes,
                          TargetConfig())  # fmt: skip
    assert torch.equal(maps.curvature, only4.curvature)
    assert torch.equal(maps.center, only4.center)


def test_per_object_channels(mini):
    ds, scene, meshes = mini
    maps = scene_targets(scene, ds.models, meshes, TargetConfig(per_object_channels=True, min_visib_fract=0.0))
    assert maps.channel_obj_ids == (3, 4)
    assert maps.center.shape[1] == 2
    shared = scene_targets(scene, ds.models, meshes, TargetConfig())
    assert torch.allclose(torch.maximum(maps.center[:, 0], maps.center[:, 1]), shared.center[:, 0])


def test_the_oracle_holds_the_channels_of_the_scene_ids_only(mini):
    """Per-object channels: the oracle's maps hold the channels of the ids the scene's GT holds, in the given
    order, each equal to that channel of the full targets (whose other channels are 0 everywhere); a scene
    holding none of the ids gets them all."""
    ds, scene, meshes = mini
    config = TargetConfig(per_object_channels=True, min_visib_fract=0.0)
    ids = (7, 4, 3)  # the scene holds parts 3 and 4, not 7
    maps = OraclePredictor(ds.models, meshes, config, ids).predict(scene)
    full = scene_targets(scene, ds.models, meshes, config, ids)
    assert maps.channel_obj_ids == (4, 3) and maps.center.shape[1] == 2
    assert not maps.exclusive_channels  # each channel a probability of its own: stage 2's noisy-OR
    assert torch.equal(maps.center, full.center[:, 1:]) and float(full.center[:, 0].abs().max()) == 0.0
    assert torch.equal(maps.curvature, full.curvature)
    missed = OraclePredictor(ds.models, meshes, config, ids, Degradation(miss_prob=1.0)).predict(scene)
    assert missed.channel_obj_ids == (4, 3) and float(missed.center.max()) == 0.0
    other = OraclePredictor(ds.models, meshes, config, (7, 8)).predict(scene)
    assert other.channel_obj_ids == (7, 8) and float(other.center.max()) == 0.0
    assert OraclePredictor(ds.models, meshes, TargetConfig()).predict(scene).channel_obj_ids is None


def test_oracle_degradations_are_seeded(mini):
    ds, scene, meshes = mini
    config = TargetConfig()
    clean = OraclePredictor(ds.models, meshes, config).predict(scene)
    d = Degradation(blur_sigma=1.0, noise_std=0.05, miss_prob=1.0, seed=3)
    a = OraclePredictor(ds.models, meshes, config, degradation=d).predict(scene)
    b = OraclePredictor(ds.models, meshes, config, degradation=d).predict(scene)
    assert torch.equal(a.center, b.center) and torch.equal(a.curvature, b.curvature)
    assert float(a.center.max()) < 0.3  # every object missed: only noise is left
    assert not torch.equal(a.curvature, clean.curvature)
    assert float(a.curvature.min()) >= 0.0 and float(a.curvature.max()) <= 1.0


def test_heatmaps_validate_shapes():
    with pytest.raises(ValueError):
        Heatmaps(torch.zeros(2, 1, 4, 5), torch.zeros(2, 4, 6), None, (0, 1))
    with pytest.raises(ValueError):
        Heatmaps(torch.zeros(2, 2, 4, 5), torch.zeros(2, 4, 5), None, (0, 1))
    with pytest.raises(ValueError):
        Heatmaps(torch.zeros(2, 1, 4, 5), torch.zeros(2, 4, 5), None, (0,))


def test_a_view_of_another_size_is_named(tmp_path: Path) -> None:
    """A colour image of another size than its view declares, or views of different sizes, is one error naming
    the image and the field (``run`` used to say "views of different sizes" with no file)."""
    import cv2

    from bop_cender.errors import DatasetError
    from bop_cender.net.predictor import scene_rgb

    ds = open_dimo(method_data.build(tmp_path / "dimo"), "real")
    scene = ds.scene(ds.scene_keys[0])
    odd = scene.views[1]
    cv2.imwrite(str(odd.rgb_path), np.zeros((odd.height // 2, odd.width // 2, 3), np.uint8))
    with pytest.raises(DatasetError, match=r"image is \d+x\d+, expected") as caught:
        scene_rgb(scene)
    assert caught.value.file == str(odd.rgb_path) and caught.value.field == "size"
    reread = ds.loader(ds.scene_keys[0])  # DIMO reads each view's size from its image: the views now differ
    with pytest.raises(DatasetError, match="views of different sizes are not supported: this one is") as caught:
        scene_rgb(reread)
    assert caught.value.file == str(odd.rgb_path) and caught.value.field == "size"
    with pytest.raises(DatasetError, match="views of different sizes are not supported: this one is") as caught:
        scene_targets(reread, ds.models, MeshCache(ds.models), TargetConfig.for_dataset("dimo"))
    assert caught.value.file == str(odd.rgb_path)
