"""The compiled CPU renderer (``render_scene``'s CPU default) gives the torch pipeline's maps bit for bit.

The torch pipeline (:mod:`bop_cender.render.raster`) is what CUDA runs and what the reference tests of
``test_rasterizer.py`` check against ray casting; the CPU now renders with the compiled loop. Every map
(depth, normals, packed face ids) must be the same bits, so that a run gives the same rows on either path
(stage 3's edge thresholds sit exactly on the curvature of a clean silhouette step: one rounding apart flips
edges). Cases: meshes through ``render_scene`` (packed: exact int64 keys), one ``RenderMesh`` against
``rasterize``/``resolve`` (int32 keys of quantised depth, as the candidate costs render: a 12-face box, coplanar
faces that tie, windows at any origin), a mesh too large for int32 keys, parts out of the frame, canvases of
several poses, threads, and the near plane (the torch pipeline's alone). The loops repeat torch's ``addcmul``
rounding as probed on the machine (fused on AVX2 builds, not with ``ATEN_CPU_CAPABILITY=default``).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial.transform import Rotation

from bop_cender.render.backend import NumbaRender, render_backend_named
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
    torch_maps = render_scene(meshes, T_t, K_t, height, width, backend=render_backend_named("torch"))
    compiled = render_scene(meshes, T_t, K_t, height, width, backend=render_backend_named("numba"))
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


def test_threads_give_the_serial_bits(on_one_and_two_threads) -> None:
    meshes = [MESHES["bracket"](), MESHES["icosphere"]()]
    T_t = torch.as_tensor(_poses(5, 2, seed=11), dtype=torch.float32)
    K_t = torch.as_tensor(np.tile(K, (5, 1, 1)), dtype=torch.float32)
    serial, threaded = on_one_and_two_threads(lambda: render_scene(meshes, T_t, K_t, H, W))
    assert torch.equal(serial.depth, threaded.depth) and torch.equal(serial.normals, threaded.normals)


def test_a_vertex_behind_the_near_plane_is_left_to_the_torch_pipeline() -> None:
    """The torch pipeline cuts faces at the near plane; the compiled loop does not, so it declines (None), and every
    backend renders such a call with the torch pipeline, the numba backend with one warning."""
    mesh = MESHES["icosphere"]()
    T = _poses(2, 1, seed=5, spread=0.0, z=10.0)  # a 25 mm sphere 10 mm in front of the camera
    T[..., 2, 3] = 10.0
    T_t, K_t = torch.as_tensor(T, dtype=torch.float32), torch.as_tensor(np.tile(K, (2, 1, 1)), dtype=torch.float32)
    assert render_compiled(mesh, T_t[..., :3, :3], T_t[..., :3, 3], K_t, H, W) is None
    default = render_scene([mesh], T_t, K_t, H, W)
    assert torch.equal(default.depth, render_scene([mesh], T_t, K_t, H, W, backend=render_backend_named("torch")).depth)
    with pytest.warns(RuntimeWarning, match="render_scene's compiled loop leaves geometry behind the near plane"):
        numba = render_scene([mesh], T_t, K_t, H, W, backend=NumbaRender(insist=True))
    assert torch.equal(default.depth, numba.depth)


def test_nothing_in_view_is_background_everywhere() -> None:
    mesh = MESHES["bracket"]()
    T = _poses(2, 1, seed=2)
    T[..., 0, 3] = 5000.0  # far to the side: every face projects outside the frame
    T_t = torch.as_tensor(T, dtype=torch.float32)
    K_t = torch.as_tensor(np.tile(K, (2, 1, 1)), dtype=torch.float32)
    out = render_scene([mesh], T_t, K_t, H, W, backend=render_backend_named("numba"))
    assert not out.mask.any() and not out.depth.any() and (out.packed_face == -1).all()


def _decal() -> trimesh.Trimesh:
    """Two coplanar overlapping squares (every depth of the smaller one ties with the larger's) and a far triangle
    repeated 600 times (21 bits of quantised depth, the face id in 10)."""

    def quad(z: float, s: float) -> list[list[float]]:
        return [[-s, -s, z], [s, -s, z], [s, s, z], [-s, s, z]]

    vertices = np.array(quad(0.0, 20.0) + quad(0.0, 15.0) + [[0, 0, 60], [1, 0, 60], [0, 1, 60]], float)
    faces = np.array([[0, 2, 1], [0, 3, 2], [4, 6, 5], [4, 7, 6], [8, 10, 9]] + [[8, 9, 10]] * 600)
    return trimesh.Trimesh(vertices, faces, process=False, validate=False)


@pytest.mark.parametrize(
    "make",
    [lambda: trimesh.creation.box((40.0, 30.0, 20.0)), _decal, lambda: bracket()],
    ids=["12-face box", "coplanar decal", "bracket"],
)
def test_one_render_mesh_with_int32_keys_is_the_torch_pipeline_bit_for_bit(make) -> None:
    """One RenderMesh (not packed): int32 keys of quantised depth, as the candidate costs render it, in windows at
    negative and positive origins. The 12-face box has 6 face bits, where torch's keys overflowed int32 before
    ``KeyCodec`` capped the depth bits at 24; the decal's coplanar faces tie on every pixel."""
    from bop_cender.render.raster import rasterize
    from bop_cender.render.resolve import resolve
    from bop_cender.render.scanline import KeyCodec
    from bop_cender.render.window import Windows

    mesh = prepare_mesh(make(), crease_angle_deg=0.0)
    assert KeyCodec.for_faces(mesh.num_faces).dtype == torch.int32
    C, h, w = 40, 60, 70
    T = torch.as_tensor(_poses(C, 1, seed=mesh.num_faces, spread=20.0), dtype=torch.float32)[:, 0]
    K_t = torch.as_tensor(np.tile(K, (C, 1, 1)), dtype=torch.float32)
    rng = np.random.default_rng(0)
    offsets = torch.as_tensor(rng.integers(-30, 60, (C, 2)), dtype=torch.int64)
    R, t = T[:, None, :3, :3], T[:, None, :3, 3]
    reference = resolve(rasterize(mesh, R, t, K_t, Windows.uniform(offsets, h, w)))
    depth, normals, faces = render_compiled(mesh, R, t, K_t, h, w, offsets=offsets)
    assert reference.mask.sum() > 0.01 * reference.mask.numel()
    assert torch.equal(reference.face, faces), f"{int((reference.face != faces).sum())} face ids differ"
    assert torch.equal(reference.depth, depth) and torch.equal(reference.normals, normals)


def test_the_rounding_of_addcmul_is_probed_not_assumed() -> None:
    """The loops repeat torch's ``addcmul`` rounding as probed on this machine (fused on AVX2 builds)."""
    from bop_cender.render import compiled_raster

    a = torch.full((9,), 1.0 + 2.0**-12)
    c = torch.full((9,), -(1.0 + 2.0**-11))
    fused = bool((torch.addcmul(c, a, a) == 2.0**-24).all())
    assert fused == compiled_raster.ADDCMUL_FUSED and compiled_raster.AVAILABLE
    assert (
        compiled_raster.torch_fma(np.float32(1 + 2**-12), np.float32(1 + 2**-12), np.float32(-(1 + 2**-11)), True)
        == 2**-24
    )
    assert (
        compiled_raster.torch_fma(np.float32(1 + 2**-12), np.float32(1 + 2**-12), np.float32(-(1 + 2**-11)), False) == 0
    )


def test_the_numba_backend_says_where_the_cpu_loops_cannot_repeat_torch(monkeypatch) -> None:
    """Where torch's ``addcmul`` rounds some elements once and others twice, the loops cannot give its bits: ``auto``
    renders with the torch pipeline after one warning, ``numba`` says why it cannot run."""
    from bop_cender.render import compiled_raster

    mesh = MESHES["bracket"]()
    T_t = torch.as_tensor(_poses(2, 1, seed=4), dtype=torch.float32)
    K_t = torch.as_tensor(np.tile(K, (2, 1, 1)), dtype=torch.float32)
    reference = render_scene([mesh], T_t, K_t, H, W, backend=render_backend_named("torch"))
    monkeypatch.setattr(compiled_raster, "AVAILABLE", False)
    with pytest.warns(RuntimeWarning, match="the CPU renders run the torch pipeline: torch's CPU addcmul rounds"):
        assert torch.equal(render_scene([mesh], T_t, K_t, H, W, backend=NumbaRender()).depth, reference.depth)
    with pytest.raises(RuntimeError, match="the numba backend's CPU loops cannot repeat the torch renderer"):
        render_scene([mesh], T_t, K_t, H, W, backend=NumbaRender(insist=True))


def test_objects_alone_and_candidate_windows_are_the_torch_render_bit_for_bit(monkeypatch) -> None:
    """``render_objects_separately`` and ``render_candidates`` render one mesh at a time (int32 keys) through the
    compiled loop on the CPU; with it switched off they take the torch pipeline: the same maps."""
    from bop_cender.render import compiled_raster
    from bop_cender.render.rasterizer import render_candidates, render_objects_separately

    meshes = [MESHES["bracket"](), MESHES["flat box"]()]
    T_t = torch.as_tensor(_poses(3, 2, seed=21), dtype=torch.float32)
    K_t = torch.as_tensor(np.tile(K, (3, 1, 1)), dtype=torch.float32)
    compiled = (render_objects_separately(meshes, T_t, K_t, H, W), render_candidates(meshes[0], T_t, K_t[:2], H, W))
    monkeypatch.setattr(compiled_raster, "AVAILABLE", False)
    torch_maps = (render_objects_separately(meshes, T_t, K_t, H, W), render_candidates(meshes[0], T_t, K_t[:2], H, W))
    assert compiled[0].depth.any() and torch.equal(compiled[0].depth, torch_maps[0].depth)
    for name in ("depth", "normals", "mask", "offsets"):
        assert torch.equal(getattr(compiled[1], name), getattr(torch_maps[1], name)), name
