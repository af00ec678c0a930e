"""The edge-point proxy of the render cost: which edges it draws, and that it ranks poses as the render cost does."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial.transform import Rotation
from scipy.stats import spearmanr

sys.path.insert(0, str(Path(__file__).parents[1]))
from method_data import gt_of, perturb  # noqa: E402

from bop_cender.pose.backend import TorchBackend, backend_named  # noqa: E402
from bop_cender.pose.edge_cost import edge_occluder  # noqa: E402
from bop_cender.pose.edge_model import edge_model, edge_model_of  # noqa: E402
from bop_cender.render.mesh import prepare_mesh  # noqa: E402

#: The edge proxy's layouts, each run by the backend object that has it (``bop_cender.pose.backend``).
LAYOUTS = {
    "kernel": backend_named("numba"),  # the CPU's compiled loop
    "cuda": backend_named("numba"),  # CUDA's kernel
    "compacted": TorchBackend(dense_edges=False),
    "dense": TorchBackend(dense_edges=True),
}
#: The default backend's render cost.
candidate_costs = backend_named("auto").candidate_costs


def edge_costs(*args, layout: str | None = None, **kwargs) -> torch.Tensor:
    """The edge proxy by the default backend (``auto``), or by the backend that runs ``layout`` (:data:`LAYOUTS`)."""
    return (backend_named("auto") if layout is None else LAYOUTS[layout]).edge_costs(*args, **kwargs)


def test_a_box_has_twelve_creases_and_six_smooth_diagonals():
    box = trimesh.creation.box(extents=(40.0, 20.0, 10.0))
    model = edge_model(box.vertices, box.faces, segment_mm=100.0)
    assert model.num_edges == 18
    assert int(model.crease.sum()) == 12
    assert model.num_segments == 18  # no edge is longer than 100 mm


def test_long_edges_are_cut_into_segments_that_cover_them():
    box = trimesh.creation.box(extents=(40.0, 20.0, 10.0))
    model = edge_model(box.vertices, box.faces, segment_mm=3.0)
    v = model.vertices.double().numpy()
    seg = model.segments.numpy()
    lengths = np.linalg.norm(v[seg[:, 1]] - v[seg[:, 0]], axis=1)
    assert lengths.max() <= 3.0 + 1e-4
    first, count = model.edge_segments.numpy().T
    edges = np.stack([v[seg[first, 0]], v[seg[first + count - 1, 1]]], axis=1)  # each edge's two ends
    edge_lengths = np.linalg.norm(edges[:, 1] - edges[:, 0], axis=1)
    per_edge = np.add.reduceat(lengths, first)
    np.testing.assert_allclose(per_edge, edge_lengths, rtol=1e-5)  # the segments of an edge are a straight chain
    assert sorted(np.round(edge_lengths[model.crease.numpy()], 3)) == sorted([40.0] * 4 + [20.0] * 4 + [10.0] * 4)


def test_duplicated_vertices_share_edges_and_degenerate_faces_are_dropped():
    box = trimesh.creation.box(extents=(30.0, 30.0, 30.0))
    soup = box.vertices[box.faces].reshape(-1, 3)  # every face with its own three vertices, as PLY files often are
    faces = np.arange(len(soup)).reshape(-1, 3)
    faces = np.vstack([faces, [[0, 0, 1]]])  # a zero-area face
    model = edge_model(soup, faces, segment_mm=100.0)
    assert model.num_edges == 18 and int(model.crease.sum()) == 12


def _cost_pair(mini, T_world_model, obj_id=3, occ=None, model=None):
    ds, scene, meshes, maps, cams, dist = mini
    T = torch.as_tensor(np.einsum("vij,njk->nvik", cams.T_cam_world, T_world_model), dtype=torch.float32)
    K = torch.as_tensor(cams.Ks, dtype=torch.float32)
    w = torch.full((len(cams.Ks),), 1.0 / len(cams.Ks))
    model = model or edge_model_of(meshes(obj_id))
    edge = edge_costs(model, T, K, dist, w, occluder_depth=occ).numpy()
    render = candidate_costs(meshes(obj_id), T, K, cams.height, cams.width, dist, w, occluder_depth=occ).numpy()
    return edge, render


def test_edge_cost_is_smallest_at_gt_and_grows_with_the_perturbation(mini):
    g = gt_of(mini[1], 3)
    poses = np.stack([perturb(g.T_world_model, a, s) for a, s in ((0, 0), (2, 1), (5, 3), (10, 6), (20, 12))])
    edge, _ = _cost_pair(mini, poses)
    assert edge[0] < 0.3
    assert np.all(np.diff(edge) > 0), edge


def test_edge_cost_ranks_random_candidates_as_the_render_cost_does(mini):
    ds, scene, meshes, maps, cams, dist = mini
    g = gt_of(scene, 3)
    rng = np.random.default_rng(3)
    n = 150
    R = Rotation.random(n, random_state=rng).as_matrix()
    poses = np.repeat(g.T_world_model[None], n, axis=0)
    poses[:, :3, :3] = R
    poses[:, :3, 3] += rng.normal(0, 4.0, (n, 3))
    poses[0] = g.T_world_model
    edge, render = _cost_pair(mini, poses)
    assert spearmanr(edge, render).statistic > 0.85
    assert int(np.argmin(edge)) == 0 == int(np.argmin(render))
    # a sparse model (every k-th edge) ranks nearly as well, and puts the render cost's best among its best
    sparse = edge_model_of(meshes(3)).sparse(40)
    assert sparse.num_segments <= 60
    coarse, _ = _cost_pair(mini, poses, model=sparse)
    assert spearmanr(coarse, render).statistic > 0.7
    assert set(np.argsort(render)[:3]) <= set(np.argsort(coarse)[:30])


def test_occluders_hide_edge_points_only_where_they_are_in_front(mini):
    ds, scene, meshes, maps, cams, dist = mini
    T = perturb(gt_of(scene, 4).T_world_model, 8.0, 3.0)[None]
    free, _ = _cost_pair(mini, T, obj_id=4)
    far = torch.full((len(cams.Ks), cams.height, cams.width), 1e5)
    assert _cost_pair(mini, T, obj_id=4, occ=far)[0] == pytest.approx(free, abs=1e-6)
    wall = torch.zeros((len(cams.Ks), cams.height, cams.width))
    wall[:, :, : cams.width // 2 + 10] = 1.0  # 1 mm from the camera: in front of everything
    hidden, _ = _cost_pair(mini, T, obj_id=4, occ=wall)
    assert hidden != pytest.approx(free, abs=1e-4)
    everywhere = torch.ones((len(cams.Ks), cams.height, cams.width))
    diagonal = float(np.hypot(cams.height, cams.width))
    assert _cost_pair(mini, T, obj_id=4, occ=everywhere)[0] == pytest.approx([diagonal])  # nothing drawn anywhere


def _camera_poses(mini, T_world_model):
    ds, scene, meshes, maps, cams, dist = mini
    T = torch.as_tensor(np.einsum("vij,njk->nvik", cams.T_cam_world, T_world_model), dtype=torch.float32)
    return T, torch.as_tensor(cams.Ks, dtype=torch.float32), torch.full((len(cams.Ks),), 1.0 / len(cams.Ks))


def test_every_layout_gives_the_compacted_costs(mini):
    """Every segment costed with a 0/1 weight (CUDA's layout: fixed shapes) and the compiled loop (the CPU's) equal
    the drawn segments compacted (torch), with and without occluders, for the full and the sparse model, a pose
    that is partly out of the image and one behind the cameras, and the dense one in chunks (one canvas per
    chunk)."""
    from bop_cender.pose import edge_cost

    ds, scene, meshes, maps, cams, dist = mini
    g = gt_of(scene, 3)
    poses = np.stack([perturb(g.T_world_model, a, s) for a, s in ((0, 0), (5, 3), (20, 12), (40, 25))])
    poses[2, :3, 3] += [60.0, 0.0, 0.0]  # partly out of some views
    poses[3, :3, 3] -= 5000.0 * cams.T_cam_world[0, 2, :3]  # behind the first camera
    T, K, w = _camera_poses(mini, poses)
    occ = torch.zeros((len(cams.Ks), cams.height, cams.width))
    occ[:, :, : cams.width // 2] = 300.0
    model = edge_model_of(meshes(3))
    for m in (model, model.sparse(40)):
        for o in (None, occ):
            compact = edge_costs(m, T, K, dist, w, occluder_depth=o, layout="compacted")
            assert compact[-1] == pytest.approx(float(np.hypot(cams.height, cams.width)))  # behind: nothing drawn
            for layout in ("dense", "kernel"):
                torch.testing.assert_close(
                    edge_costs(m, T, K, dist, w, occluder_depth=o, layout=layout), compact, rtol=1e-5, atol=1e-4
                )
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(edge_cost, "DENSE_CHUNK_SEGMENTS", 1)  # one canvas per chunk
        torch.testing.assert_close(
            edge_costs(model, T, K, dist, w, layout="dense"), edge_costs(model, T, K, dist, w, layout="compacted")
        )


def test_the_cpu_default_is_the_kernel_and_its_bits_do_not_depend_on_the_threads(mini, on_one_and_two_threads):
    """With no layout named, a CPU call runs the compiled loop; each canvas is summed by one thread in a fixed
    order, so 1 and 2 threads give the same bits. An unknown backend is one clear error."""
    ds, scene, meshes, maps, cams, dist = mini
    g = gt_of(scene, 3)
    poses = np.stack([perturb(g.T_world_model, a, s) for a, s in ((0, 0), (5, 3), (20, 12), (3, 1), (9, 4))])
    T, K, w = _camera_poses(mini, poses)
    model = edge_model_of(meshes(3))
    one, two = on_one_and_two_threads(lambda: edge_costs(model, T, K, dist, w))
    assert torch.equal(one, two) and torch.equal(one, edge_costs(model, T, K, dist, w, layout="kernel"))
    with pytest.raises(ValueError, match="unknown backend 'sparse'; expected one of auto, torch, numba"):
        backend_named("sparse")


def test_a_non_finite_pose_costs_the_diagonal_in_every_layout(mini):
    """A NaN or infinite pose draws nothing: the image diagonal, never an index error (on CUDA, a device-side
    assert that would break the process's context), and the finite poses beside it keep their costs."""
    ds, scene, meshes, maps, cams, dist = mini
    g = gt_of(scene, 3).T_world_model
    bad_rotation, bad_translation = g.copy(), g.copy()
    bad_rotation[0, 0] = np.nan
    bad_translation[:3, 3] = np.inf
    T, K, w = _camera_poses(mini, np.stack([g, bad_rotation, bad_translation]))
    model = edge_model_of(meshes(3))
    diagonal = float(np.hypot(cams.height, cams.width))
    for layout in ("compacted", "dense", "kernel"):
        for occ in (None, torch.zeros_like(dist)):
            costs = edge_costs(model, T, K, dist, w, occluder_depth=occ, layout=layout)
            assert costs[0] < 0.3 and costs[1:].tolist() == pytest.approx([diagonal, diagonal]), (layout, costs)


def test_the_dense_layout_never_waits_for_the_device(mini, monkeypatch):
    """No ``nonzero``, ``item`` or size read from a tensor in a dense call: on CUDA nothing would synchronise
    before the result is read. Counted on the CPU by torch.profiler (the same operators run on either device)."""
    from torch.profiler import ProfilerActivity, profile

    ds, scene, meshes, maps, cams, dist = mini
    T, K, w = _camera_poses(mini, perturb(gt_of(scene, 3).T_world_model, 5, 3)[None])
    model = edge_model_of(meshes(3))
    assert model.projection.seg_edge.numel() == model.num_segments  # the tables are built once per model, not per call
    syncing = {"aten::nonzero", "aten::item", "aten::_local_scalar_dense", "aten::repeat_interleave"}

    def counted(layout: str) -> int:
        with profile(activities=[ProfilerActivity.CPU]) as prof:
            edge_costs(model, T, K, dist, w, occluder_depth=torch.zeros_like(dist), layout=layout)
        return sum(e.count for e in prof.key_averages() if e.key in syncing)

    assert counted("compacted") > 0  # the compacted layout reads sizes from tensors (the counter works)
    assert counted("dense") == 0


def test_a_segment_is_projected_from_its_edge_ends():
    """The projection tables place each segment of a cut edge where the cut points are: lerping the edge ends'
    homogeneous coordinates at the segment's fractions, then dividing, gives the projection of the cut points."""
    box = trimesh.creation.box(extents=(40.0, 20.0, 10.0))
    model = edge_model(box.vertices, box.faces, segment_mm=3.0)
    proj = model.projection
    ends = proj.ends.T[:, :3].double()
    a = torch.lerp(ends[proj.seg_from], ends[proj.seg_to], proj.frac_a.double()[:, None])
    b = torch.lerp(ends[proj.seg_from], ends[proj.seg_to], proj.frac_b.double()[:, None])
    v = model.vertices.double()
    torch.testing.assert_close(a, v[model.segments[:, 0]], atol=1e-4, rtol=0)
    torch.testing.assert_close(b, v[model.segments[:, 1]], atol=1e-4, rtol=0)
    assert proj.ends.shape[1] == 8  # only the box's corners are projected, not the cut points
    sparse = model.sparse(30).projection
    assert sparse.seg_edge.shape[0] == model.sparse(30).num_segments


def test_a_pose_outside_every_image_costs_the_diagonal(mini):
    ds, scene, meshes, maps, cams, dist = mini
    T = gt_of(scene, 3).T_world_model.copy()
    T[:3, 3] += 5000.0
    edge, render = _cost_pair(mini, T[None])
    diagonal = [np.hypot(cams.height, cams.width)]
    assert edge == pytest.approx(diagonal, rel=1e-5) and render == pytest.approx(diagonal, rel=1e-5)


def test_wrong_shapes_are_named():
    box = prepare_mesh(trimesh.creation.box(extents=(10.0, 10.0, 10.0)))
    model = edge_model_of(box)
    T = torch.eye(4).repeat(2, 3, 1, 1)
    with pytest.raises(ValueError, match="K"):
        edge_costs(model, T, torch.eye(3).repeat(2, 1, 1), torch.zeros(3, 8, 8), torch.ones(3))
    with pytest.raises(ValueError, match="view_weights"):
        edge_costs(model, T, torch.eye(3).repeat(3, 1, 1), torch.zeros(3, 8, 8), torch.ones(2))
    with pytest.raises(ValueError, match="segment_mm"):
        edge_model(box.vertices.numpy(), box.faces.numpy(), segment_mm=0.0)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cuda_gives_the_cpu_costs(mini):
    """CUDA's default layout (the CUDA kernel where numba's CUDA target works, :mod:`bop_cender.pose.cuda_edge_kernel`;
    else dense) and the dense one give the CPU's costs, with and without placed objects."""
    from bop_cender.pose import cuda_edge_kernel

    ds, scene, meshes, maps, cams, dist = mini
    g = gt_of(scene, 3)
    poses = np.stack([perturb(g.T_world_model, a, s) for a, s in ((0, 0), (5, 3), (20, 12))])
    T, K, w = _camera_poses(mini, poses)
    model = edge_model_of(meshes(3))
    occ = torch.zeros_like(dist)
    occ[:, :, : occ.shape[2] // 2] = 300.0
    layouts = ["dense"] + (["cuda"] if cuda_edge_kernel.GUARD.unavailable() is None else [])
    for o in (None, occ):
        cpu = edge_costs(model, T, K, dist, w, occluder_depth=o)
        args = (model.to("cuda"), T.cuda(), K.cuda(), dist.cuda(), w.cuda())
        gpu_o = None if o is None else o.cuda()
        default = edge_costs(*args, occluder_depth=gpu_o)
        assert default.device.type == "cuda" and torch.equal(default, edge_costs(*args, occluder_depth=gpu_o,
                                                                                  layout=layouts[-1]))  # fmt: skip
        for layout in layouts:
            torch.testing.assert_close(edge_costs(*args, occluder_depth=gpu_o, layout=layout).cpu(), cpu, rtol=1e-4,
                                       atol=1e-4)  # fmt: skip


def test_a_candidate_that_duplicates_a_placed_object_draws_almost_nothing(mini):
    from bop_cender.pose.occluders import occluder_depth
    from bop_cender.pose.types import PlacedObject

    ds, scene, meshes, maps, cams, dist = mini
    T = gt_of(scene, 3).T_world_model
    placed = occluder_depth([PlacedObject(3, T, 0.0, 0)], cams, meshes, backend_named("auto"))
    free, _ = _cost_pair(mini, T[None])
    twice, _ = _cost_pair(mini, T[None], occ=edge_occluder(placed))
    assert free[0] < 0.3
    assert twice[0] == pytest.approx(np.hypot(cams.height, cams.width), rel=1e-5)
    # the other part, beside it, keeps its fit
    assert _cost_pair(mini, gt_of(scene, 4).T_world_model[None], obj_id=4, occ=edge_occluder(placed))[0][0] < 1.0


def test_the_edge_occluder_is_the_nearest_placed_surface_around_each_pixel():
    occ = torch.zeros(1, 5, 5)
    occ[0, 2, 2] = 100.0
    occ[0, 2, 3] = 50.0
    wide = edge_occluder(occ)[0]
    assert wide[1, 1] == 100.0 and wide[2, 2] == 50.0 and wide[1, 4] == 50.0 and wide[0, 0] == 0.0


def _one_segment(a: np.ndarray, b: np.ndarray):
    """An EdgeModel of one always-drawn crease segment from ``a`` to ``b`` (model frame, mm)."""
    from bop_cender.pose.edge_model import EdgeModel

    facing = torch.tensor([[[0.0, 0.0, 0.0, -1.0], [0.0, 0.0, 0.0, -1.0]]])  # n . eye - d = 1 > 0: faces the camera
    return EdgeModel(
        vertices=torch.tensor(np.stack([a, b]), dtype=torch.float32),
        segments=torch.tensor([[0, 1]]),
        planes=facing,
        crease=torch.tensor([True]),
        edge_segments=torch.tensor([[0, 1]]),
    )


def test_edge_points_are_projected_by_the_full_intrinsics_and_dropped_behind_the_near_plane():
    """On a distance map equal to the column (d = u - 0.5 at pixel-centre coordinates u), the cost of one segment is
    the mean column of its projected sample points: the midpoint of its projected ends, ``K (R X + t) / z`` with a
    skewed K (a NumPy reference); a segment with an end behind ``near`` is not drawn (the image diagonal)."""
    H, W = 200, 300
    dist = torch.arange(W, dtype=torch.float32).expand(1, H, W).contiguous()
    K = np.array([[250.0, 7.0, 140.0], [0.0, 240.0, 95.0], [0.0, 0.0, 1.0]])
    R = Rotation.from_euler("xyz", [8, -5, 12], degrees=True).as_matrix()
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, [3.0, -2.0, 400.0]
    a, b = np.array([-20.0, 5.0, 3.0]), np.array([15.0, -8.0, -4.0])

    def cost(model, T_cm, near=1.0):
        return float(edge_costs(model, torch.tensor(T_cm[None, None], dtype=torch.float32),
                                torch.tensor(K[None], dtype=torch.float32), dist, torch.ones(1), near=near)[0])  # fmt: skip

    def u(p):
        x = K @ (R @ p + T[:3, 3])
        return x[0] / x[2]

    assert cost(_one_segment(a, b), T) == pytest.approx((u(a) + u(b)) / 2 - 0.5, abs=1e-3)
    # a 3 mm segment 10 mm in front of the camera: costed where both ends are in front of `near`, not drawn where
    # one end is behind it
    close = T.copy()
    close[2, 3] = 10.0
    c, d = np.array([0.5, 0.3, -1.5]), np.array([-0.4, -0.2, 1.2])
    z = (R @ np.stack([c, d]).T)[2] + 10.0
    near = float(z.mean())
    assert z.min() < near < z.max() and z.min() > 1.0

    def u_close(p):
        x = K @ (R @ p + close[:3, 3])
        return x[0] / x[2]

    assert cost(_one_segment(c, d), close, near=1.0) == pytest.approx((u_close(c) + u_close(d)) / 2 - 0.5, abs=1e-2)
    assert cost(_one_segment(c, d), close, near=near) == pytest.approx(np.hypot(H, W))


def test_the_serial_and_threaded_compilations_give_the_same_bits(mini, monkeypatch):
    """Both compilations of each compiled loop (``numba_loops.canvas_loop``) run and agree bit for bit, whatever the
    machine's core count (the threaded one called directly, on the threads numba has)."""
    from bop_cender.pose import edge_kernel, window_kernel

    ds, scene, meshes, maps, cams, dist = mini
    g = gt_of(scene, 3)
    T, K, w = _camera_poses(mini, np.stack([perturb(g.T_world_model, a, s) for a, s in ((0, 0), (5, 3), (20, 9))]))
    model = edge_model_of(meshes(3))
    serial = edge_costs(model, T, K, dist, w, layout="kernel")
    monkeypatch.setattr(edge_kernel, "canvas_costs", edge_kernel.canvas_costs.threaded)
    assert torch.equal(edge_costs(model, T, K, dist, w, layout="kernel"), serial)

    V, H, W = dist.shape
    gen = torch.Generator().manual_seed(0)
    depth = torch.where(torch.rand((2 * V, H, W), generator=gen) > 0.5, 400.0, 0.0)
    normals = torch.nn.functional.normalize(torch.randn((2 * V, H, W, 3), generator=gen), dim=-1)
    args = [depth, normals, depth[:V].flip(1), normals[:V].flip(2), dist, torch.zeros((V, 2), dtype=torch.long),
            torch.rand((V, H, W), generator=gen) > 0.9, 3.0]  # fmt: skip
    before = window_kernel.window_costs(*args)
    monkeypatch.setattr(window_kernel, "_composite_costs", window_kernel._composite_costs.threaded)
    assert torch.equal(window_kernel.window_costs(*args), before)
    args[6] = args[6].to(torch.uint8)  # a 0/1 mask of another dtype selects the same pixels
    assert torch.equal(window_kernel.window_costs(*args), before)


def test_with_one_thread_the_compiled_loops_start_no_thread_pool():
    """With one torch thread (each `run` process) the compiled loops run serially and never start numba's OpenMP
    pool, whose idle threads spin between calls and took half a core from the other worker (``numba_loops``). In a
    fresh process: other tests here may have started the pool."""
    import subprocess
    import sys

    code = """
import numpy as np, torch, trimesh
import numba.np.ufunc.parallel as pool
from bop_cender.pose.backend import backend_named
from bop_cender.pose.edge_model import edge_model
from bop_cender.pose.window_kernel import window_costs
torch.set_num_threads(1)
box = trimesh.creation.box(extents=(40.0, 20.0, 10.0))
T = torch.eye(4).repeat(2, 1, 1, 1)
T[..., 2, 3] = 300.0
K = torch.tensor([[[500.0, 0, 32], [0, 500, 24], [0, 0, 1]]])
dist = torch.rand(1, 48, 64)
cost = backend_named("auto").edge_costs(edge_model(box.vertices, box.faces), T, K, dist, torch.ones(1))
z = torch.zeros(2, 8, 8)
window_costs(z, torch.zeros(2, 8, 8, 3), z[:1], torch.zeros(1, 8, 8, 3), dist, torch.zeros(1, 2, dtype=torch.long),
             torch.ones(1, 8, 8, dtype=torch.bool), 3.0)
assert bool(torch.isfinite(cost).all()) and cost.shape == (2,)
print("pool started" if pool._is_initialized else "no pool")
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "no pool"
