"""Targets files, the toolkit's dataset constants, PLY vertices as the toolkit reads them, depth crops."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from bop_cender.data.targets_file import read_targets, write_targets
from bop_cender.data.types import ObjectModel
from bop_cender.errors import DatasetError
from bop_cender.eval.depth_render import render_depth_crops
from bop_cender.eval.matching import Target
from bop_cender.eval.model_points import eval_vertices
from bop_cender.eval.toolkit_constants import mspd_width, vsd_delta_for
from bop_cender.render.mesh import prepare_mesh
from bop_cender.render.rasterizer import render_objects_separately


def test_targets_round_trip_and_errors(tmp_path: Path) -> None:
    targets = [Target(1, 0, 5, 2), Target(12317, 4, 1, 1)]
    write_targets(tmp_path / "t.json", targets)
    assert read_targets(tmp_path / "t.json") == targets
    (tmp_path / "bad.json").write_text(json.dumps([{"scene_id": 1, "im_id": 0, "obj_id": 5, "inst_count": 0}]))
    with pytest.raises(DatasetError, match=r"\[0\]\.inst_count: expected a positive integer"):
        read_targets(tmp_path / "bad.json")


def test_toolkit_constants() -> None:
    assert mspd_width("tless", "test", 240).value == 720
    assert mspd_width("tless", "test_canon", 240).value == 2560
    assert mspd_width("tless", "train_pbr", 240).value == 720
    assert mspd_width("lmo", "test", 100).value == 640
    assert mspd_width("itodd", "test", 100).value == 1280
    unknown = mspd_width("dimo", "real", 320)
    assert unknown.value == 320 and "unknown to the toolkit" in unknown.source
    assert vsd_delta_for("itodd").value == 5.0 and vsd_delta_for("tless").value == 15.0
    assert vsd_delta_for("dimo").value == 15.0 and "not in the toolkit's table" in vsd_delta_for("dimo").source
    assert vsd_delta_for("dimo", 7.5).value == 7.5


def test_ascii_ply_vertices_are_parsed_as_float64_like_the_toolkit(tmp_path: Path) -> None:
    """trimesh reads ASCII 'property float' as float32; the toolkit parses the text with float()."""
    path = tmp_path / "obj_000001.ply"
    path.write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
        "18.70469475 0.1 -3.3\n1.0 2.0 3.0\n0.0 0.0 1.0\n3 0 1 2\n"
    )
    model = ObjectModel(1, path, 20.0, np.array([0.0, 0.0, -3.3]), np.array([18.70469475, 1.9, 6.3]))
    pts = eval_vertices(model)
    assert pts[0, 0] == 18.70469475 and pts[0, 1] == 0.1 and pts.dtype == np.float64
    assert model.mesh.vertices[0, 0] != 18.70469475  # the float32 value: why this module exists
    binary = tmp_path / "obj_000002.ply"
    binary.write_bytes(trimesh.exchange.ply.export_ply(trimesh.creation.box(), encoding="binary"))
    model2 = ObjectModel(2, binary, 2.0, np.full(3, -0.5), np.ones(3))
    np.testing.assert_array_equal(eval_vertices(model2), model2.mesh.vertices)


def test_depth_crops_hold_the_whole_silhouette_inside_the_image() -> None:
    mesh = prepare_mesh(trimesh.creation.box(extents=(60.0, 40.0, 30.0)))
    K = np.array([[300.0, 0.0, 80.0], [0.0, 300.0, 60.0], [0.0, 0.0, 1.0]])
    T = np.tile(np.eye(4), (3, 1, 1))
    T[:, :3, :3] = Rotation.from_euler("xyz", [25, -30, 10], degrees=True).as_matrix()
    T[:, 2, 3] = 500.0
    T[1, 0, 3] = 130.0  # partly beyond the right border
    T[2, 0, 3] = 2000.0  # wholly outside the image
    full = render_objects_separately([mesh], T[:, None], np.stack([K] * 3), 120, 160).depth[:, 0].numpy()
    crops = render_depth_crops(mesh, T, np.stack([K] * 3), 120, 160)
    for e in range(2):
        y0, x0, y1, x1 = crops.window(e)
        assert np.count_nonzero(full[e]) == np.count_nonzero(crops.depth[e]) > 0
        np.testing.assert_array_equal(full[e, y0:y1, x0:x1], crops.depth[e])
    assert crops.window(2) is None and not full[2].any()
    corners_z = 500.0 + (np.array(np.meshgrid([-30, 30], [-20, 20], [-15, 15])).reshape(3, -1).T @ T[0, :3, :3].T)[:, 2]
    assert corners_z.min() - 1e-3 <= full[0][full[0] > 0].min() and full[0].max() <= corners_z.max() + 1e-3


def test_mspd_hot_vertex_prune_is_exact_for_near_gt_estimates(monkeypatch) -> None:
    """Estimates a few degrees off a cylinder's GT: many symmetries nearly tie, the second prune must keep the
    minimum (bit for bit the exhaustive result)."""
    from bop_cender.eval import pose_errors as errors
    from bop_cender.geometry.symmetry import ContinuousSymmetry, symmetry_transforms

    pts = np.asarray(trimesh.creation.cylinder(radius=30.0, height=80.0, sections=48).subdivide().vertices)
    sym_R, sym_t = symmetry_transforms(
        [[1, 0, 0, 0, 0, -1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1]], [ContinuousSymmetry((0, 0, 1))]
    )
    rng = np.random.default_rng(4)
    R_g = Rotation.random(30, random_state=5).as_matrix()
    t_g = np.c_[rng.uniform(-100, 100, 30), rng.uniform(-80, 80, 30), rng.uniform(650, 900, 30)]
    R_e = Rotation.from_rotvec(np.radians(rng.uniform(1, 4, (30, 1))) * rng.normal(size=(30, 3))).as_matrix() @ R_g
    t_e = t_g + rng.normal(0, 3, (30, 3))
    K = np.array([[1075.0, 0.0, 360.0], [0.0, 1073.0, 270.0], [0.0, 0.0, 1.0]])
    pruned = errors.mspd(R_e, t_e, R_g, t_g, K, pts, sym_R, sym_t)
    monkeypatch.setattr(errors, "PRUNE_MIN_SYMMETRIES", 10**9)
    np.testing.assert_array_equal(pruned, errors.mspd(R_e, t_e, R_g, t_g, K, pts, sym_R, sym_t))
