"""Tests for bop_cender.eval.pose_errors: hand-computed cases, symmetries, early-outs, exact shortcuts, toolkit numbers."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from bop_cender.eval import pose_errors as errors
from bop_cender.eval.pose_errors import add, adi, hull_vertices, mspd, mssd, re, spheres_overlap, te
from bop_cender.geometry.symmetry import ContinuousSymmetry, symmetry_transforms

FIXTURE = Path(__file__).parent / "fixtures" / "toolkit_reference.json"
K = np.array([[572.4, 0.0, 325.3], [0.0, 573.6, 242.0], [0.0, 0.0, 1.0]])
IDENTITY = (np.eye(3)[None], np.zeros((1, 3)))
FLIP_X = [1, 0, 0, 0, 0, -1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1]  # 180 deg about x


def cube(edge: float = 10.0) -> np.ndarray:
    """The 8 corners ``(8, 3)`` of a cube centred at the origin."""
    return np.array(np.meshgrid(*[[-edge / 2, edge / 2]] * 3, indexing="ij")).reshape(3, -1).T


def cylinder(radius: float = 30.0, height: float = 80.0, sections: int = 72) -> np.ndarray:
    return np.asarray(trimesh.creation.cylinder(radius=radius, height=height, sections=sections).vertices)


def random_poses(n: int, seed: int, spread_t: float = 15.0, spread_r: float = 0.3):
    rng = np.random.default_rng(seed)
    R_g = Rotation.random(n, random_state=seed).as_matrix()
    t_g = np.c_[rng.uniform(-100, 100, n), rng.uniform(-100, 100, n), rng.uniform(500, 900, n)]
    R_e = Rotation.from_rotvec(rng.normal(0, spread_r, (n, 3))).as_matrix() @ R_g
    return R_e, t_g + rng.normal(0, spread_t, (n, 3)), R_g, t_g


# ------------------------------------------------------------------------------------------ hand-computed


def test_translated_cube_by_3mm():
    pts = cube()
    t_g = np.array([0.0, 0.0, 1000.0])
    t_e = t_g + [3.0, 0.0, 0.0]
    assert mssd(np.eye(3), t_e, np.eye(3), t_g, pts, *IDENTITY)[0] == pytest.approx(3.0, abs=1e-12)
    assert add(np.eye(3), t_e, np.eye(3), t_g, pts)[0] == pytest.approx(3.0, abs=1e-12)
    assert adi(np.eye(3), t_e, np.eye(3), t_g, pts)[0] == pytest.approx(3.0, abs=1e-12)
    assert te(t_e, t_g)[0] == pytest.approx(3.0)
    assert re(np.eye(3), np.eye(3))[0] == pytest.approx(0.0, abs=1e-6)


def test_mspd_known_projection_offset():
    """A 10 mm shift in x at ~1 m: the largest pixel shift is fx * 10 / z at the nearest corner (z = 995)."""
    pts = cube(10.0)
    t_g = np.array([0.0, 0.0, 1000.0])
    e = mspd(np.eye(3), t_g + [10.0, 0.0, 0.0], np.eye(3), t_g, K, pts, *IDENTITY)
    assert e[0] == pytest.approx(572.4 * 10.0 / 995.0, rel=1e-12)


def test_rotation_error_degrees():
    R90 = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    assert re(R90, np.eye(3))[0] == pytest.approx(90.0)
    assert re(np.stack([np.eye(3), R90 @ R90]), np.eye(3)) == pytest.approx([0.0, 180.0], abs=1e-6)


# ------------------------------------------------------------------------------------------ symmetries


def test_listed_discrete_symmetry_scores_zero():
    pts = cube(10.0) * [1.0, 2.0, 3.0]  # a box: 180 deg about x maps it onto itself
    sym_R, sym_t = symmetry_transforms([FLIP_X])
    R_g, t_g = Rotation.from_euler("xyz", [10, 20, 30], degrees=True).as_matrix(), np.array([5.0, -3.0, 700.0])
    R_e, t_e = R_g @ sym_R[1], R_g @ sym_t[1] + t_g
    assert mssd(R_e, t_e, R_g, t_g, pts, sym_R, sym_t)[0] == pytest.approx(0.0, abs=1e-9)
    assert mspd(R_e, t_e, R_g, t_g, K, pts, sym_R, sym_t)[0] == pytest.approx(0.0, abs=1e-9)
    # without the symmetry the same pose is far off: the set matters
    assert mssd(R_e, t_e, R_g, t_g, pts, *IDENTITY)[0] > 10.0
    # ADD-S of a symmetric object: vertices land on vertices, so 0, while ADD is not
    assert adi(R_e, t_e, R_g, t_g, pts)[0] == pytest.approx(0.0, abs=1e-9)
    assert add(R_e, t_e, R_g, t_g, pts)[0] > 10.0


def test_continuous_symmetry_is_sampled_like_the_toolkit():
    """At k * 2 pi / 315 the error is 0; half a step off it is 2 r sin(pi / 630), small but NOT 0."""
    radius = 30.0
    pts = cylinder(radius)
    sym_R, sym_t = symmetry_transforms([FLIP_X], [ContinuousSymmetry((0.0, 0.0, 1.0))])
    assert len(sym_R) == 630
    R_g, t_g = Rotation.from_euler("xyz", [40, -20, 10], degrees=True).as_matrix(), np.array([20.0, 10.0, 800.0])
    step = 2 * math.pi / 315
    angles = np.array([7 * step, 100 * step, 7.5 * step, 200.5 * step])
    R_e = R_g @ Rotation.from_rotvec(angles[:, None] * [0.0, 0.0, 1.0]).as_matrix()
    t_e = np.broadcast_to(t_g, (4, 3))
    e = mssd(R_e, t_e, R_g, t_g, pts, sym_R, sym_t)
    assert e[:2] == pytest.approx([0.0, 0.0], abs=1e-9)
    assert e[2:] == pytest.approx([2 * radius * math.sin(math.pi / 630)] * 2, rel=1e-9)  # ~0.2992 mm
    p = mspd(R_e, t_e, R_g, t_g, K, pts, sym_R, sym_t)
    assert p[:2] == pytest.approx([0.0, 0.0], abs=1e-9)
    assert np.all(p[2:] > 0.05)


# ------------------------------------------------------------------------------------------ early-outs


def test_inf_early_out_at_diameter():
    pts = cube(10.0)
    diameter = float(np.sqrt(300.0))
    t_g = np.array([0.0, 0.0, 600.0])
    t_e = np.stack([t_g + [diameter, 0, 0], t_g + [0, diameter * (1 - 1e-9), 0], t_g + [0, 0, 2 * diameter]])
    R = np.eye(3)
    for f in (mssd, add, adi):
        kwargs = {"diameter": diameter}
        e = f(R, t_e, R, t_g, pts, *IDENTITY, **kwargs) if f is mssd else f(R, t_e, R, t_g, pts, **kwargs)
        assert np.isinf(e[0]) and np.isinf(e[2]), f.__name__
        # MSSD and ADD of a pure translation are its length; for ADI the GT corners at y = +5 are 10 mm
        # closer to the shifted corners at y = -5 + d, so half the distances are d - 10: mean d - 5
        assert e[1] == pytest.approx(diameter - (5.0 if f is adi else 0.0), rel=1e-6), f.__name__
        # without the diameter there is no early-out
        e_all = f(R, t_e, R, t_g, pts, *IDENTITY) if f is mssd else f(R, t_e, R, t_g, pts)
        assert np.all(np.isfinite(e_all))
    assert spheres_overlap(t_e, t_g, diameter).tolist() == [False, True, False]
    # MSPD has no early-out in the toolkit
    assert np.all(np.isfinite(mspd(R, t_e, R, t_g, K, pts, *IDENTITY)))


# ------------------------------------------------------------------------------------------ exact shortcuts


def test_hull_shortcut_equals_all_vertices():
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=40.0)
    pts = np.asarray(mesh.vertices) * [1.4, 1.0, 0.6] + 5.0 * np.sin(np.asarray(mesh.vertices)[:, 1:2] / 7.0)
    hull = hull_vertices(pts)
    assert len(hull) < len(pts)
    sym_R, sym_t = symmetry_transforms([FLIP_X], [ContinuousSymmetry((0.0, 0.0, 1.0))])
    R_e, t_e, R_g, t_g = random_poses(12, seed=1)
    full = mssd(R_e, t_e, R_g, t_g, pts, sym_R, sym_t)
    assert mssd(R_e, t_e, R_g, t_g, hull, sym_R, sym_t) == pytest.approx(full, rel=1e-12, abs=1e-12)


def test_hull_of_flat_points_falls_back_to_all():
    flat = np.c_[np.random.default_rng(0).normal(size=(20, 2)), np.zeros(20)]
    assert hull_vertices(flat).shape == (20, 3)


def test_prune_and_chunking_do_not_change_the_result(monkeypatch):
    pts = cylinder(sections=96)
    sym_R, sym_t = symmetry_transforms([FLIP_X], [ContinuousSymmetry((0.0, 0.0, 1.0), (2.0, -1.0, 0.0))])
    R_e, t_e, R_g, t_g = random_poses(20, seed=2)
    Ks = np.broadcast_to(K, (20, 3, 3)).copy()
    Ks[:, 0, 0] += np.arange(20)  # per-estimate intrinsics
    pruned = (mssd(R_e, t_e, R_g, t_g, pts, sym_R, sym_t), mspd(R_e, t_e, R_g, t_g, Ks, pts, sym_R, sym_t))
    small = (
        mssd(R_e, t_e, R_g, t_g, pts, sym_R, sym_t, max_elements=1000),
        mspd(R_e, t_e, R_g, t_g, Ks, pts, sym_R, sym_t, max_elements=1000),
    )
    monkeypatch.setattr(errors, "PRUNE_MIN_SYMMETRIES", 10**9)
    exhaustive = (mssd(R_e, t_e, R_g, t_g, pts, sym_R, sym_t), mspd(R_e, t_e, R_g, t_g, Ks, pts, sym_R, sym_t))
    for a, b, c in zip(pruned, small, exhaustive, strict=True):
        np.testing.assert_allclose(a, c, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(b, c, rtol=1e-12, atol=1e-12)


def test_batched_equals_one_by_one_and_shapes():
    pts = cube() * [1, 2, 3]
    sym_R, sym_t = symmetry_transforms([FLIP_X])
    R_e, t_e, R_g, t_g = random_poses(5, seed=3)
    batch = mspd(R_e, t_e, R_g, t_g, K, pts, sym_R, sym_t)
    one = [mspd(R_e[i], t_e[i].reshape(3, 1), R_g[i], t_g[i], K, pts, sym_R, sym_t)[0] for i in range(5)]
    assert batch.shape == (5,)
    np.testing.assert_allclose(batch, one, rtol=1e-13)
    # one GT against many estimates broadcasts
    assert mssd(R_e, t_e, R_g[0], t_g[0], pts, sym_R, sym_t).shape == (5,)
    with pytest.raises(ValueError, match="t_est"):
        mssd(R_e, t_e[:, :2], R_g, t_g, pts, sym_R, sym_t)


# ------------------------------------------------------------------------------------------ official numbers


def test_matches_official_toolkit_numbers():
    ref = json.loads(FIXTURE.read_text())["pose_errors"]
    model = ref["model"]
    pts = np.asarray(model["vertices"])
    discrete = model.get("symmetries_discrete", [])
    continuous = [ContinuousSymmetry(tuple(s["axis"]), tuple(s["offset"])) for s in model["symmetries_continuous"]]
    sym_R, sym_t = symmetry_transforms(discrete, continuous, ref["max_sym_disc_step"])
    cases = ref["cases"]
    R_e = np.array([c["R_est"] for c in cases]).reshape(-1, 3, 3)
    R_g = np.array([c["R_gt"] for c in cases]).reshape(-1, 3, 3)
    t_e = np.array([c["t_est"] for c in cases])
    t_g = np.array([c["t_gt"] for c in cases])
    d = model["diameter"]
    K_ref = np.asarray(ref["K"])

    def expected(name: str) -> np.ndarray:
        return np.array([c[name] for c in cases], dtype=np.float64)

    got = {
        "mssd": mssd(R_e, t_e, R_g, t_g, pts, sym_R, sym_t, diameter=d),
        "mssd_hull": mssd(R_e, t_e, R_g, t_g, hull_vertices(pts), sym_R, sym_t, diameter=d),
        "mspd": mspd(R_e, t_e, R_g, t_g, K_ref, pts, sym_R, sym_t),
        "add": add(R_e, t_e, R_g, t_g, pts, diameter=d),
        "adi": adi(R_e, t_e, R_g, t_g, pts, diameter=d),
        "re": re(R_e, R_g),
        "te": te(t_e, t_g),
    }
    for name, value in got.items():
        want = expected(name.removesuffix("_hull"))
        assert np.array_equal(np.isinf(value), np.isinf(want)), name
        np.testing.assert_allclose(value[np.isfinite(want)], want[np.isfinite(want)], rtol=0, atol=1e-6, err_msg=name)
    assert np.isinf(expected("mssd")).sum() >= 1  # the fixture covers the early-out (at ||dt|| == diameter)


@pytest.mark.parametrize("spread_t", [15.0, 80.0])
def test_errors_beyond_a_bound_are_inf_and_the_others_exact(spread_t):
    """``beyond`` (BOP'24 detection needs exact errors below its largest thresholds only): a pair whose error is at
    least the bound is ``inf``, every other error bit for bit what it is without the bound; with the symmetries of a
    cylinder (probe bounds) and of an asymmetric box (none)."""
    pts = cylinder(sections=96)
    sym_R, sym_t = symmetry_transforms([FLIP_X], [ContinuousSymmetry((0.0, 0.0, 1.0), (0.0, 0.0, 0.0))])
    R_e, t_e, R_g, t_g = random_poses(60, seed=4, spread_t=spread_t)
    for S_R, S_t in ((sym_R, sym_t), IDENTITY):
        exact_mm = mssd(R_e, t_e, R_g, t_g, pts, S_R, S_t)
        exact_px = mspd(R_e, t_e, R_g, t_g, K, pts, S_R, S_t)
        for exact, bounded in (
            (exact_mm, mssd(R_e, t_e, R_g, t_g, pts, S_R, S_t, beyond=float(np.median(exact_mm)))),
            (exact_px, mspd(R_e, t_e, R_g, t_g, K, pts, S_R, S_t, beyond=float(np.median(exact_px)))),
        ):
            bound = float(np.median(exact))
            assert np.array_equal(bounded[exact < bound], exact[exact < bound])
            assert np.isinf(bounded[exact >= bound]).all() and np.isinf(bounded).sum() == (exact >= bound).sum()
