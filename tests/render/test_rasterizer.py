"""The rasterizer against independent ray casting (trimesh + embree), and its own invariants.

Images are small (160x128) so that the reference stays fast. Agreement asked for: masks equal except
at most 0.5 % of the object's pixels, all on the reference's boundary; mask centroids within 0.05 px
(a reference shifted by half a pixel must fail that); depth within 0.01 mm and normals within 1 degree
where both hit the same face.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from bop_cender.render.mesh import prepare_mesh
from bop_cender.render.raster import rasterize
from bop_cender.render.rasterizer import render_candidates, render_objects_separately, render_scene
from bop_cender.render.scanline import KeyCodec, scan
from bop_cender.render.window import Windows

try:
    from tests.render.reference import K_matrix, bracket, holed_plate, mask_agreement, pose, raycast, transformed
except ImportError:  # pytest's default import mode puts tests/render itself on sys.path
    from reference import K_matrix, bracket, holed_plate, mask_agreement, pose, raycast, transformed

H, W = 128, 160
K = K_matrix(310.0, 305.0, 80.3, 63.6)

# The `device` fixture (CPU, and CUDA where present) is in tests/conftest.py.


def interpolated_normals(
    mesh_cam: trimesh.Trimesh, corner_normals_cam: np.ndarray, tri: np.ndarray, points: np.ndarray
) -> np.ndarray:
    """Reference normals ``(P, 3)``: the corner normals interpolated at the 3D hit points."""
    bary = trimesh.triangles.points_to_barycentric(mesh_cam.triangles[tri], points)
    n = np.einsum("pi,pia->pa", bary, corner_normals_cam[tri])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def compare(mesh: trimesh.Trimesh, T: np.ndarray, crease: float = 30.0, device: str = "cpu") -> dict:
    """Render one mesh at ``T_cam_model`` and ray-cast it; assert agreement; return the statistics."""
    rm = prepare_mesh(mesh, crease, device=device)
    out = render_scene([rm], torch.as_tensor(T[None, None], device=device), K[None], H, W)
    assert not torch.isnan(out.depth).any() and not torch.isnan(out.normals).any()
    mesh_cam = transformed(mesh, T)
    ref = raycast(mesh_cam, K, H, W)
    mask = out.mask[0].cpu().numpy()
    fraction, on_boundary, shift = mask_agreement(mask, ref.mask)
    assert fraction <= 0.005 and on_boundary, (fraction, on_boundary)
    assert shift <= 0.05, shift
    face = out.face[0].cpu().numpy()
    same = mask & ref.mask & (face == ref.tri)
    assert same.sum() >= 0.98 * ref.mask.sum()
    depth = out.depth[0].cpu().numpy()
    assert np.abs(depth[same] - ref.depth[same]).max() <= 0.01
    corner_cam = np.einsum("ab,fib->fia", T[:3, :3], rm.corner_normals.cpu().numpy().astype(np.float64))
    expected = interpolated_normals(mesh_cam, corner_cam, ref.tri[same], ref.point[same])
    mine = out.normals[0].cpu().numpy()[same]
    angle = np.degrees(np.arccos(np.clip((mine * expected).sum(1), -1.0, 1.0)))
    assert angle.max() <= 1.0, angle.max()
    assert np.abs(np.linalg.norm(mine, axis=1) - 1).max() < 1e-5
    return {"pixels": int(ref.mask.sum()), "fraction": fraction, "shift": shift}


@pytest.mark.parametrize(
    ("make", "T"),
    [
        (lambda: trimesh.creation.box((40, 30, 20)), pose((20, -35, 10), (3, -4, 180))),
        (lambda: trimesh.creation.cylinder(radius=15, height=40, sections=32), pose((70, 10, 0), (-5, 2, 170))),
        (lambda: bracket(), pose((-30, 40, 25), (0, 0, 260))),
        (lambda: bracket(), pose((100, -20, 60), (8, -6, 240))),
        (lambda: trimesh.creation.icosphere(subdivisions=2, radius=20), pose((0, 0, 0), (0, 0, 150))),
    ],
    ids=["box", "cylinder", "bracket-a", "bracket-b", "sphere"],
)
def test_single_objects_match_raycasting(make, T, device) -> None:
    stats = compare(make(), T, device=device)
    assert stats["pixels"] > 500


def test_thin_and_holed_plates_match_raycasting() -> None:
    # A 1 mm plate seen obliquely (its rim is a fraction of a pixel wide) and a plate with holes
    # through which the background shows.
    compare(trimesh.creation.box((50, 40, 1.0)), pose((60, 20, 0), (0, 0, 150)))
    stats = compare(holed_plate(4.0), pose((25, -15, 5), (2, 1, 140)))
    assert stats["pixels"] > 1000
    # Straight on, the middle hole is centred on the optical axis: both see through it.
    T = pose((0, 0, 0), (0, 0, 140))
    plate = raycast(transformed(holed_plate(4.0), T), K, H, W)
    out = render_scene([prepare_mesh(holed_plate(4.0))], T[None, None], K[None], H, W)
    hole_centre = (63, 80)
    assert not out.mask[0][hole_centre] and not plate.mask[hole_centre]
    assert out.mask[0][hole_centre[0], hole_centre[1] + 20]  # plate material between the holes


def test_half_pixel_shift_is_detected() -> None:
    mesh = bracket()
    T = pose((-30, 40, 25), (0, 0, 260))
    out = render_scene([prepare_mesh(mesh)], T[None, None], K[None], H, W)
    mask = out.mask[0].numpy()
    _, _, shift_ok = mask_agreement(mask, raycast(transformed(mesh, T), K, H, W).mask)
    _, _, shift_bad = mask_agreement(mask, raycast(transformed(mesh, T), K, H, W, shift=0.0).mask)
    assert shift_ok <= 0.05
    assert shift_bad > 0.05  # the centroid check would catch a half-pixel convention slip


def test_objects_occlude_each_other_like_raycasting_the_pile(device) -> None:
    meshes = [bracket(), trimesh.creation.box((40, 30, 20)), trimesh.creation.cylinder(radius=12, height=50)]
    T = np.stack(
        [pose((-30, 40, 25), (0, 0, 260)), pose((10, 20, 30), (15, 10, 230)), pose((80, 0, 10), (-20, -5, 215))]
    )
    render = render_scene([prepare_mesh(m, device=device) for m in meshes], T[None], K[None], H, W)
    pile = [transformed(m, t) for m, t in zip(meshes, T, strict=True)]
    ref = raycast(trimesh.util.concatenate(pile), K, H, W)
    offsets = np.cumsum([0] + [len(m.faces) for m in meshes])
    ref_instance = np.where(ref.mask, np.searchsorted(offsets, ref.tri, side="right") - 1, -1)
    instance = render.instance[0].cpu().numpy()
    for m in range(len(meshes)):
        fraction, on_boundary, shift = mask_agreement(instance == m, ref_instance == m)
        assert fraction <= 0.01 and on_boundary and shift <= 0.05, (m, fraction, on_boundary, shift)
    assert (instance >= 0).sum() > 0 and len(np.unique(instance)) == 4  # every object is visible
    same = (instance == ref_instance) & ref.mask
    depth = render.depth[0].cpu().numpy()
    assert np.median(np.abs(depth[same] - ref.depth[same])) <= 0.01
    local = render.face[0].cpu().numpy()
    assert np.mean(local[same] + offsets[instance[same]] == ref.tri[same]) > 0.98


def test_object_partly_outside_the_image() -> None:
    stats = compare(bracket(), pose((-30, 40, 25), (-62, 35, 240)))  # cut by the left and bottom borders
    assert stats["pixels"] > 500
    out = render_scene([prepare_mesh(bracket())], pose((0, 0, 0), (-500, 0, 240))[None, None], K[None], H, W)
    assert not out.mask.any()  # entirely outside: nothing drawn


def test_geometry_behind_the_camera_is_clipped_and_never_nan() -> None:
    # A large slab under the camera that reaches behind it (vertices at z < 0), seen from just above;
    # the visible part of its top face is in front of the near plane.
    slab = trimesh.creation.box((400, 20, 600))
    T = pose((0, 0, 0), (0, 40, 100))  # spans z = -200 .. 400, top face at y = 30 (below the camera)
    out = render_scene([prepare_mesh(slab)], T[None, None], K[None], H, W)
    assert not torch.isnan(out.depth).any() and not torch.isnan(out.normals).any()
    ref = raycast(transformed(slab, T), K, H, W)
    mask = out.mask[0].numpy()
    fraction, on_boundary, _ = mask_agreement(mask, ref.mask)
    assert fraction <= 0.005 and on_boundary
    both = mask & ref.mask
    assert np.abs(out.depth[0].numpy()[both] - ref.depth[both]).max() <= 0.01
    assert out.depth[0][out.mask[0]].min() >= 1.0  # nothing nearer than the near plane
    # Inside a box: seen from inside, its walls are back faces and nothing is drawn; turned inside out,
    # its walls face the camera, and the side wall (z from -130 to 170 mm) is cut by the near plane.
    room = trimesh.creation.box((300, 300, 300))
    T = pose((0, 0, 0), (120, 0, 20))
    out = render_scene([prepare_mesh(room)], T[None, None], K[None], H, W)
    assert not out.mask.any()
    room.invert()
    out = render_scene([prepare_mesh(room)], T[None, None], K[None], H, W)
    assert not torch.isnan(out.depth).any() and not torch.isnan(out.normals).any()
    ref = raycast(transformed(room, T), K, H, W)
    assert ref.mask.all() and out.mask.all()
    near_wall = out.normals[0, :, :, 0] > 0.5  # the side wall at x = -30 mm, normal +x
    assert near_wall.sum() > 100
    assert np.abs(out.depth[0].numpy() - ref.depth).max() <= 0.01


def test_shared_edges_have_no_holes_and_no_double_coverage() -> None:
    # A grid of triangles (both diagonal directions) in a plane facing the camera, with vertices exactly
    # on pixel corners, then on pixel centres, then anywhere: every pixel centre is covered once.
    n = 9
    xs, ys = np.meshgrid(np.linspace(-40, 40, n), np.linspace(-30, 30, n))
    verts = np.stack([xs.ravel(), ys.ravel(), np.zeros(n * n)], 1)
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, i * n + j + 1, (i + 1) * n + j, (i + 1) * n + j + 1
            faces += [[a, c, b], [b, c, d]] if (i + j) % 2 else [[a, c, d], [a, d, b]]
    grid = trimesh.Trimesh(verts, np.array(faces), process=False)  # normals -z: towards the camera
    for fx, cx in ((200.0, 80.0), (200.0, 80.5), (237.3, 80.17)):
        Kp = K_matrix(fx, fx, cx, 64.0)
        rm = prepare_mesh(grid, 0.0)
        T = torch.as_tensor(pose((0, 0, 0), (0, 0, 200)), dtype=torch.float32)
        windows = Windows.uniform(torch.zeros((1, 2), dtype=torch.int64), H, W)
        counts = _fragment_counts(rm, T, torch.as_tensor(Kp, dtype=torch.float32), windows)
        assert counts.max() == 1  # no pixel drawn twice by the plane's triangles
        # No holes: exactly the pixel centres inside the projected rectangle, top and left sides included.
        u, v = np.arange(W) + 0.5, np.arange(H) + 0.5
        x0, x1 = cx + fx * -40 / 200, cx + fx * 40 / 200
        y0, y1 = 64.0 + fx * -30 / 200, 64.0 + fx * 30 / 200
        expected = ((v >= y0) & (v < y1))[:, None] & ((u >= x0) & (u < x1))[None, :]
        assert np.array_equal(counts.reshape(H, W) == 1, expected)


def _fragment_counts(rm, T: torch.Tensor, Kp: torch.Tensor, windows: Windows) -> np.ndarray:
    """Fragments per pixel of one canvas (through the scanline pass itself)."""
    captured = {}

    def spy(*args, **kwargs):
        fragments = scan(*args, **kwargs)
        captured["lin"] = fragments.lin
        return fragments

    import bop_cender.render.raster as raster_module

    original = raster_module.scan
    raster_module.scan = spy
    try:
        rasterize(rm, T[None, None, :3, :3], T[None, None, :3, 3], Kp[None], windows)
    finally:
        raster_module.scan = original
    return np.bincount(captured["lin"].numpy(), minlength=windows.total)


def test_windows_equal_the_full_frame(device) -> None:
    mesh = prepare_mesh(bracket(), device=device)
    rng = np.random.default_rng(3)
    T = np.stack(
        [[pose(tuple(rng.uniform(-180, 180, 3)), (x, y, 250)) for x, y in ((0, 0), (-70, 40))] for _ in range(3)]
    )  # (B=3, V=2): the second view's object is cut by the image border
    Ks = np.stack([K, K_matrix(290.0, 290.0, 79.1, 65.2)])
    cand = render_candidates(mesh, torch.as_tensor(T, device=device), Ks, H, W)
    S = cand.size
    assert S % 8 == 0
    for b in range(3):
        for v in range(2):
            full = render_scene([mesh], torch.as_tensor(T[b, v][None, None], device=device), Ks[v][None], H, W)
            v0, u0 = cand.offsets[b, v].tolist()
            rows = slice(max(v0, 0), min(v0 + S, H))
            cols = slice(max(u0, 0), min(u0 + S, W))
            win = (slice(rows.start - v0, rows.stop - v0), slice(cols.start - u0, cols.stop - u0))
            assert torch.equal(cand.mask[b, v][win], full.mask[0][rows, cols])
            if device.type == "cpu":  # the same arithmetic: the same bits
                assert torch.equal(cand.normals[b, v][win], full.normals[0][rows, cols])
                assert torch.equal(cand.depth[b, v][win], full.depth[0][rows, cols])
            else:  # CUDA contracts the window's and the frame's interpolation into FMAs differently (H200: the
                # masks equal, the normals not to the bit)
                torch.testing.assert_close(cand.normals[b, v][win], full.normals[0][rows, cols], rtol=1e-5, atol=1e-5)
                torch.testing.assert_close(cand.depth[b, v][win], full.depth[0][rows, cols], rtol=1e-5, atol=1e-4)
            # Everything of the object that is in the image is inside the window.
            assert cand.mask[b, v][win].sum() == full.mask[0].sum()


def test_depth_only_rasterising_skips_the_normals_and_keeps_depth_bit_identical(device) -> None:
    mesh = prepare_mesh(bracket(), device=device)
    rng = np.random.default_rng(8)
    T = np.stack([[pose(tuple(rng.uniform(-180, 180, 3)), (x, -20, 240))] for x in (-40, 0, 50)])  # (B=3, V=1)
    both = render_candidates(mesh, torch.as_tensor(T, device=device), K[None], H, W)
    depth_only = render_candidates(mesh, torch.as_tensor(T, device=device), K[None], H, W, normals=False)
    assert depth_only.normals is None
    assert torch.equal(depth_only.depth, both.depth) and torch.equal(depth_only.mask, both.mask)
    assert both.mask.sum() > 1000
    Tt = torch.as_tensor(T[:, 0], dtype=torch.float32, device=device)
    windows = Windows.uniform(torch.zeros((3, 2), dtype=torch.int64, device=device), H, W)
    Kt = torch.as_tensor(np.stack([K] * 3), dtype=torch.float32, device=device)
    full = rasterize(mesh, Tt[:, None, :3, :3], Tt[:, None, :3, 3], Kt, windows)
    lean = rasterize(mesh, Tt[:, None, :3, :3], Tt[:, None, :3, 3], Kt, windows, normals=False)
    assert torch.equal(lean.table[9:], full.table[9:]) and torch.equal(lean.keys, full.keys)
    assert not lean.table[:9].any() and full.table[:9].any()


def test_a_batch_equals_one_candidate_at_a_time() -> None:
    mesh = prepare_mesh(bracket())
    rng = np.random.default_rng(4)
    T = np.stack(
        [[pose(tuple(rng.uniform(-180, 180, 3)), tuple(rng.uniform(-10, 10, 2)) + (260,))] * 2 for _ in range(5)]
    )
    T[:, 1, :3, 3] += (5.0, -3.0, 20.0)
    Ks = np.stack([K, K])
    batch = render_candidates(mesh, T, Ks, H, W, window=96)
    for b in range(5):
        one = render_candidates(mesh, T[b : b + 1], Ks, H, W, window=96)
        assert torch.equal(one.normals[0], batch.normals[b])
        assert torch.equal(one.depth[0], batch.depth[b])
        assert torch.equal(one.offsets[0], batch.offsets[b])
    again = render_candidates(mesh, T, Ks, H, W, window=96)
    assert torch.equal(again.normals, batch.normals)  # deterministic


def test_objects_rendered_separately_are_full_silhouettes() -> None:
    meshes = [bracket(), trimesh.creation.box((40, 30, 20))]
    T = np.stack([pose((-30, 40, 25), (0, 0, 260)), pose((10, 20, 30), (15, 10, 230))])
    rms = [prepare_mesh(m) for m in meshes]
    alone = render_objects_separately(rms, T[None], K[None], H, W)
    together = render_scene(rms, T[None], K[None], H, W)
    for m in range(2):
        single = render_scene([rms[m]], T[m][None, None], K[None], H, W)
        assert torch.equal(alone.depth[0, m], single.depth[0])
        visible = together.instance[0] == m
        assert bool((alone.mask[0, m] | ~visible).all())  # the visible part lies inside the silhouette
    assert (alone.mask[0, 0] & alone.mask[0, 1]).any()  # the two overlap in the image: one occludes


def test_large_meshes_use_exact_float_keys_and_both_key_kinds_agree(monkeypatch) -> None:
    sphere = trimesh.creation.icosphere(subdivisions=6, radius=30)  # 81920 faces: face ids need 17 bits
    assert KeyCodec.for_faces(len(sphere.faces)).dtype == torch.int64
    assert KeyCodec.for_faces(684).dtype == torch.int32
    assert KeyCodec.for_faces(684, exact=True).dtype == torch.int64  # scenes of several meshes
    compare(sphere, pose((10, 20, 30), (2, -3, 160)))
    # One mesh gets quantised int32 keys; they draw what exact int64 keys draw.
    mesh, T = prepare_mesh(bracket()), pose((100, -20, 60), (8, -6, 240))
    quantised = render_candidates(mesh, T[None, None], K[None], H, W)
    monkeypatch.setattr(KeyCodec, "for_faces", staticmethod(lambda n, exact=False: KeyCodec(torch.int64, 32, 0)))
    exact = render_candidates(mesh, T[None, None], K[None], H, W)
    assert quantised.mask.sum() > 1000
    assert torch.equal(quantised.mask, exact.mask)
    assert torch.equal(quantised.normals, exact.normals)
