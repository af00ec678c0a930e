"""The compiled CPU renderer (``render_scene``'s CPU default) gives the torch pipeline's maps bit for bit.

The torch pipeline (:mod:`bop_cender.render.raster`) is what CUDA runs and what the reference tests of
``test_rasterizer.py`` check against ray casting; the CPU now renders with the compiled loop. Every map
(depth, normals, packed face ids) must be the same bits, so that a run gives the same rows on either path
(stage 3's edge thresholds sit exactly on the curvature of a clean silhouette step: one rounding apart flips
edges). Cases: single meshes (int32 keys), packed scenes (exact int64 keys), a mesh too large for int32 keys,
parts out of the frame, canvases of several poses, threads, and the near plane (the torch pipeline's alone).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial.transform import Rotation

from bop_cender.render.compiled_raster import render_compiled
from bop_cender.render.mesh import prepare_mesh
from bop_cender.render.rasterizer import render_scene

try:
    from tests.render.reference import K_matrix, bracket, holed_plate
except ImportError:  # pytest's default import mode puts tests/render itself on sys.path
    from reference import K_matrix, bracket, holed_plate

H, W = 96, 128
K = K_matrix(300.0, 295.0, 64.3, 47.6)


def _poses(n_views: int, n_objects: int, seed: int, spread: float = 40.0, z: float = 300.0) -> np.ndarray:
    """``(V, M, 4, 4)`` random rotations, objects spread about the optical axis (some partly out of frame)."""
    rng = np.random.default_rng(seed)
    T = np.tile(np.eye(4), (n_views, n_objects, 1, 1))
    T[..., :3, :3] = (
        Rotation.random(n_views * n_objects, random_state=seed).as_matrix().reshape(n_views, n_objects, 3, 3)
    )
    T[..., :2, 3] = rng.normal(0.0, spread, (n_views, n_objects, 2))
    T[..., 2, 3] = z + rng.uniform(-60.0, 60.0, (n_views, n_objects))
    return T


def _assert_same(meshes, T: np.ndarray, Ks: np.ndarray, height: int = H, width: int = W) -> None:
    T_t, K_t = torch.as_tensor(T, dtype=torch.float32), torch.as_tensor(Ks, dtype=torch.float32)
    torch_maps = render_scene(meshes, T_t, K_t, height, width, compiled=False)
    compiled = render_scene(meshes, T_t, K_t, height, width, compiled=True)
    assert torch_maps.mask.any()  # something was drawn
    for name in ("depth", "normals", "packed_face"):
        a, b = getattr(torch_maps, name), getattr(compiled, name)
        assert a.dtype == b.dtype and a.shape == b.shape, name
        assert torch.equal(a, b), f"{name}: {int((a != b).sum())} values differ"
    assert torch.equal(torch_maps.instance, compiled.instance)


MESHES = {
    "bracket": lambda: prepare_mesh(bracket()),
    "holed_plate": lambda: prepare_mesh(holed_plate()),
    "icosphere": lambda: prepare_mesh(trimesh.creation.icosphere(subdivisions=3, radius=25.0)),
    "flat box": lambda: prepare_mesh(trimesh.creation.box((40.0, 30.0, 20.0)), crease_angle_deg=0.0),
}


@pytest.mark.parametrize("name", sorted(MESHES))
def test_one_mesh_in_many_canvases_is_the_torch_render_bit_for_bit(name: str) -> None:
    mesh = MESHES[name]()
    T = _poses(6, 1, seed=len(name))
    _assert_same([mesh], T, np.tile(K, (6, 1, 1)))


def test_a_packed_scene_is_the_torch_render_bit_for_bit() -> None:
    """Several meshes (exact int64 keys, ties to the larger packed face id), occluding each other."""
    meshes = [MESHES[n]() for n in sorted(MESHES)]
    T = _poses(4, len(meshes), seed=7, spread=15.0)
    _assert_same(meshes, T, np.tile(K, (4, 1, 1)))
    same_pose = np.repeat(T[:, :1], 2, axis=1)  # one mesh twice at one pose: every depth ties
    _assert_same([meshes[0], meshes[0]], same_pose, np.tile(K, (4, 1, 1)))


def test_a_mesh_whose_face_ids_need_more_than_15_bits_uses_exact_keys_alike() -> None:
    sphere = prepare_mesh(trimesh.creation.icosphere(subdivisions=6, radius=30.0))  # 81,920 faces
    _assert_same([sphere], _poses(2, 1, seed=3), np.tile(K, (2, 1, 1)))


def test_threads_give_the_serial_bits() -> None:
    meshes = [MESHES["bracket"](), MESHES["icosphere"]()]
    T_t = torch.as_tensor(_poses(5, 2, seed=11), dtype=torch.float32)
    K_t = torch.as_tensor(np.tile(K, (5, 1, 1)), dtype=torch.float32)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        serial = render_scene(meshes, T_t, K_t, H, W)
        torch.set_num_threads(2)
        threaded = render_scene(meshes, T_t, K_t, H, W)
    finally:
        torch.set_num_threads(before)
    assert torch.equal(serial.depth, threaded.depth) and torch.equal(serial.normals, threaded.normals)


def test_a_vertex_behind_the_near_plane_is_left_to_the_torch_pipeline() -> None:
    """The torch pipeline cuts faces at the near plane; the compiled loop does not, so it declines (None), the
    default falls back, and ``compiled=True`` says why it cannot."""
    mesh = MESHES["icosphere"]()
    T = _poses(2, 1, seed=5, spread=0.0, z=10.0)  # a 25 mm sphere 10 mm in front of the camera
    T[..., 2, 3] = 10.0
    T_t, K_t = torch.as_tensor(T, dtype=torch.float32), torch.as_tensor(np.tile(K, (2, 1, 1)), dtype=torch.float32)
    assert render_compiled(mesh, T_t[..., :3, :3], T_t[..., :3, 3], K_t, H, W) is None
    default = render_scene([mesh], T_t, K_t, H, W)
    assert torch.equal(default.depth, render_scene([mesh], T_t, K_t, H, W, compiled=False).depth)
    with pytest.raises(ValueError, match="behind the near plane"):
        render_scene([mesh], T_t, K_t, H, W, compiled=True)


def test_nothing_in_view_is_background_everywhere() -> None:
    mesh = MESHES["bracket"]()
    T = _poses(2, 1, seed=2)
    T[..., 0, 3] = 5000.0  # far to the side: every face projects outside the frame
    T_t = torch.as_tensor(T, dtype=torch.float32)
    K_t = torch.as_tensor(np.tile(K, (2, 1, 1)), dtype=torch.float32)
    out = render_scene([mesh], T_t, K_t, H, W, compiled=True)
    assert not out.mask.any() and not out.depth.any() and (out.packed_face == -1).all()
