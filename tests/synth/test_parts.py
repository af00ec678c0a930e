"""Procedural parts: valid closed meshes, BOP-centred, sizes in range, and exactly their listed symmetry group."""

import math
from functools import cache

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bop_cender.geometry.symmetry import ContinuousSymmetry, continuous_step_count, symmetry_transforms
from bop_cender.synth.models_info import points_diameter, symmetry_deviation
from bop_cender.synth.parts import (
    FLIP_X,
    PART_TYPES,
    Part,
    cyclic_z,
    dihedral_z,
    make_bracket,
    make_carrier,
    make_flange,
    make_hex_part,
    make_part_set,
    make_shaft,
    make_slotted_plate,
    make_tube,
)

SEEDS = (0, 1, 2)
#: Every shape we check: the six part types, the carrier, and the symmetric variant of the bracket.
MAKERS = PART_TYPES | {"carrier": make_carrier, "bracket_equal": lambda rng: make_bracket(rng, equal_legs=True)}
REL_TOL = 1e-3  # symmetry check: fraction of the diameter
N_CONT = continuous_step_count(0.01)  # 315


@cache
def build(name: str, seed: int) -> Part:
    return MAKERS[name](np.random.default_rng(seed))


def tolerance(part: Part) -> float:
    return REL_TOL * points_diameter(part.mesh.vertices)


def deviation(part: Part, R: np.ndarray, t: np.ndarray, both_ways: bool = True) -> np.ndarray:
    """Relative deviation (fraction of the diameter) of each transform; inf when clearly not a symmetry."""
    tol = tolerance(part)
    return symmetry_deviation(part.mesh, R, t, search_radius=2 * tol, both_ways=both_ways) / (tol / REL_TOL)


def indices_to_check(n_transforms: int, stride: int = 15) -> np.ndarray:
    """All discrete transforms; for continuous sets every ``stride``-th step plus the first ones of each block.

    The subset is closed under inversion (rotation k <-> N - k; the flips are their own inverse), so
    checking one direction per entry checks both directions of every entry.
    """
    if n_transforms <= 32:
        return np.arange(n_transforms)
    assert N_CONT % stride == 0
    firsts = [
        b * N_CONT + k for b in range(n_transforms // N_CONT) for k in (1, 2, 3, N_CONT - 3, N_CONT - 2, N_CONT - 1)
    ]
    return np.unique(np.r_[np.arange(0, n_transforms, stride), firsts])


# --------------------------------------------------------------------------- mesh validity


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("name", sorted(MAKERS))
def test_mesh_is_closed_outward_centred_and_sized(name, seed):
    part = build(name, seed)
    mesh = part.mesh
    assert part.name == name.removesuffix("_equal")
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0  # outward normals
    assert mesh.area_faces.min() > 1e-6  # mm^2: no degenerate faces
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    np.testing.assert_allclose((lo + hi) / 2, 0.0, atol=1e-6)
    if name != "carrier":
        assert 20.0 <= (hi - lo).max() <= 150.0
    assert len(mesh.faces) < 5000


@pytest.mark.parametrize("name", sorted(PART_TYPES))
def test_largest_extent_within_range_over_many_seeds(name):
    extents = [np.ptp(PART_TYPES[name](np.random.default_rng(100 + s)).mesh.vertices, axis=0).max() for s in range(15)]
    assert min(extents) >= 20.0 and max(extents) <= 150.0
    assert max(extents) - min(extents) > 10.0  # sizes are really drawn


def test_bracket_default_scale_and_face_count():
    faces = [len(make_bracket(np.random.default_rng(s), holes_per_leg=2).mesh.faces) for s in range(5)]
    assert all(400 <= f <= 900 for f in faces)


def test_curved_surfaces_are_finely_tessellated():
    tube = make_tube(np.random.default_rng(0))
    z = tube.mesh.vertices[:, 2]
    top_ring = tube.mesh.vertices[np.isclose(z, z.max())]
    assert len(top_ring) == 2 * 64  # outer and inner circle


def test_deterministic_per_seed_and_varied_across_seeds():
    for name, maker in MAKERS.items():
        a, b = maker(np.random.default_rng(7)), maker(np.random.default_rng(7))
        np.testing.assert_array_equal(a.mesh.vertices, b.mesh.vertices, err_msg=name)
        np.testing.assert_array_equal(a.mesh.faces, b.mesh.faces, err_msg=name)
        assert a.params == b.params
        c = maker(np.random.default_rng(8))
        assert c.params != a.params, name


# --------------------------------------------------------------------------- symmetries


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("name", sorted(MAKERS))
def test_every_listed_symmetry_maps_the_mesh_onto_itself(name, seed):
    part = build(name, seed)
    R, t = symmetry_transforms(part.symmetries_discrete, part.symmetries_continuous, max_sym_disc_step=0.01)
    idx = indices_to_check(len(R), stride=15 if seed == 0 else 45)  # other seeds: a sparser subset
    dev = deviation(part, R[idx], t[idx], both_ways=False)
    assert dev.max() <= REL_TOL, f"{name}: transforms {idx[dev > REL_TOL]} deviate by {dev.max():.2e} x diameter"


def test_continuous_checks_use_the_bop_steps():
    """The continuous transforms checked above are exactly the rotations by k * 2 pi / 315 about z."""
    part = build("tube", 0)
    R, _ = symmetry_transforms(part.symmetries_discrete, part.symmetries_continuous, max_sym_disc_step=0.01)
    assert len(R) == 2 * N_CONT
    for stride in (15, 45):  # the subsets are closed under inversion: one direction per entry suffices
        _inverse_indices(R[indices_to_check(len(R), stride)])
    for k in indices_to_check(len(R)):
        block, step = divmod(int(k), N_CONT)
        expected = Rotation.from_rotvec([0.0, 0.0, step * 2 * math.pi / N_CONT]).as_matrix()
        if block == 1:
            expected = expected @ FLIP_X
        np.testing.assert_allclose(R[k], expected, atol=1e-12)


def _as_matrices(flat: list[list[float]]) -> np.ndarray:
    return np.asarray(flat, dtype=np.float64).reshape(-1, 4, 4)


@pytest.mark.parametrize("name", sorted(MAKERS))
def test_discrete_entries_are_distinct_proper_rotations_closed_under_composition(name):
    part = build(name, 0)
    T = _as_matrices(part.symmetries_discrete)
    if len(T) == 0:
        return
    R = T[:, :3, :3]
    np.testing.assert_allclose(T[:, :3, 3], 0.0)  # bbox centre on every axis: no translation
    np.testing.assert_allclose(T[:, 3], np.tile([0.0, 0, 0, 1], (len(T), 1)))
    np.testing.assert_allclose(np.einsum("sji,sjk->sik", R, R), np.tile(np.eye(3), (len(R), 1, 1)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0)
    group = np.concatenate([np.eye(3)[None], R])
    assert np.all(np.abs(group[:, None] - group[None]).max(axis=(2, 3)) + np.eye(len(group)) > 1e-6)  # distinct
    if part.symmetries_continuous:
        return  # the flip alone is a group together with the continuous axis
    for a in group:
        for b in group:
            assert np.abs(group - a @ b).max(axis=(1, 2)).min() < 1e-9


FLIP = [[1.0, 0, 0, 0, 0, -1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1]]
Z = [ContinuousSymmetry((0.0, 0.0, 1.0), (0.0, 0.0, 0.0))]


@pytest.mark.parametrize("maker", [make_shaft, make_tube])
def test_shaft_and_tube_are_continuous_plus_flip(maker):
    for seed in SEEDS:
        part = maker(np.random.default_rng(seed))
        assert part.symmetries_continuous == Z and part.symmetries_discrete == FLIP


def test_hex_part_is_six_fold_plus_flip():
    for kind in ("nut", "bar"):
        part = make_hex_part(np.random.default_rng(0), kind=kind)
        assert part.params["kind"] == kind
        assert len(part.symmetries_discrete) == 11 and part.symmetries_discrete == dihedral_z(6)
        assert not part.symmetries_continuous


@pytest.mark.parametrize("n_holes", [3, 4, 5, 6, 8])
def test_flange_with_n_holes_is_n_fold_plus_flip(n_holes):
    part = make_flange(np.random.default_rng(n_holes), n_holes=n_holes)
    assert len(part.symmetries_discrete) == 2 * n_holes - 1 and part.symmetries_discrete == dihedral_z(n_holes)
    # The generators Rz(2 pi / n) and Rx(pi) map the mesh onto itself, hence so does the whole group
    # (the listed entries are closed under composition: tested above for the default flange).
    R, t = symmetry_transforms([part.symmetries_discrete[0], part.symmetries_discrete[n_holes - 1]])
    np.testing.assert_allclose(R[1:], [_rot_z(360.0 / n_holes), FLIP_X], atol=1e-12)
    assert deviation(part, R[1:], t[1:]).max() <= REL_TOL


def test_bracket_group():
    assert build("bracket", 0).symmetries_discrete == []  # unequal legs: asymmetric
    half_turn = np.array([[0.0, 0, 1, 0], [0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 0, 1]])
    np.testing.assert_array_equal(_as_matrices(build("bracket_equal", 0).symmetries_discrete)[0], half_turn)


def test_slotted_plate_and_carrier_groups():
    plate = _as_matrices(build("slotted_plate", 0).symmetries_discrete)[:, :3, :3]
    np.testing.assert_allclose(
        plate, [np.diag([-1.0, -1, 1]), np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1])], atol=1e-15
    )
    assert build("carrier", 0).symmetries_discrete == cyclic_z(2)


def _rot_z(deg: float) -> np.ndarray:
    return Rotation.from_euler("z", deg, degrees=True).as_matrix()


@pytest.mark.parametrize(
    ("name", "part", "R"),
    [
        ("flange 4 holes, 30 deg", lambda: make_flange(np.random.default_rng(0), n_holes=4), _rot_z(30.0)),
        ("flange 4 holes, 45 deg", lambda: make_flange(np.random.default_rng(0), n_holes=4), _rot_z(45.0)),
        ("hex part, 10 deg", lambda: make_hex_part(np.random.default_rng(0)), _rot_z(10.0)),
        ("hex nut, 30 deg", lambda: make_hex_part(np.random.default_rng(0), kind="nut"), _rot_z(30.0)),
        ("carrier flipped", lambda: build("carrier", 0), FLIP_X),
        ("slotted plate, 90 deg", lambda: build("slotted_plate", 0), _rot_z(90.0)),
        ("shaft, 90 deg about x", lambda: build("shaft", 0), Rotation.from_euler("x", 90, degrees=True).as_matrix()),
        ("bracket, diagonal", lambda: build("bracket", 0), np.array([[0.0, 0, 1], [0, -1, 0], [1, 0, 0]])),
    ],
)
def test_a_non_symmetry_fails_the_same_check(name, part, R):
    """The check can fail. Flange by 45 deg: every rotated vertex still lies on the flat faces; the face
    centroids of the hole walls are what catch it; the flipped carrier likewise."""
    part = part()
    assert deviation(part, R[None], np.zeros((1, 3)))[0] > REL_TOL, name


def _candidates() -> np.ndarray:
    """The 24 rotations of the cube, rotations about z by 15 deg steps, and half-turns about in-plane axes."""
    rz = Rotation.from_euler("z", np.arange(0.0, 360.0, 15.0)[:, None], degrees=True).as_matrix()
    diagonal = np.array([[0.0, 0, 1], [0, -1, 0], [1, 0, 0]])
    return np.concatenate([Rotation.create_group("O").as_matrix(), rz, rz @ FLIP_X, diagonal[None]])


def _inverse_indices(R: np.ndarray) -> np.ndarray:
    """Index of each rotation's inverse within ``R (S, 3, 3)``; fails if one is missing."""
    diff = np.abs(R.transpose(0, 2, 1)[:, None] - R[None]).max(axis=(2, 3))  # (S, S)
    assert np.all(diff.min(axis=1) < 1e-9), "set not closed under inversion"
    return diff.argmin(axis=1)


@pytest.mark.parametrize("name", sorted(MAKERS))
def test_no_symmetry_is_missing_from_the_list(name):
    """Among many candidate rotations, exactly those in the listed group map the part onto itself."""
    part = build(name, 0)
    cands = _candidates()
    inverse = _inverse_indices(cands)  # the candidate set is closed under inversion
    one_way = deviation(part, cands, np.zeros((len(cands), 3)), both_ways=False) <= REL_TOL
    symmetric = one_way & one_way[inverse]
    if part.symmetries_continuous:  # the group is every rotation about z, with and without the flip
        listed = np.isclose(np.abs(cands[:, 2, 2]), 1.0)
    else:
        group, _ = symmetry_transforms(part.symmetries_discrete)
        listed = np.array([np.abs(group - R).max(axis=(1, 2)).min() < 1e-9 for R in cands])
    np.testing.assert_array_equal(symmetric, listed)


# --------------------------------------------------------------------------- part sets and arguments


def test_part_set_has_every_type_and_is_deterministic():
    parts = make_part_set(np.random.default_rng(3), 8)
    assert len(parts) == 8 and {p.name for p in parts} == set(PART_TYPES)
    assert {p.name for p in make_part_set(np.random.default_rng(4), 6)} == set(PART_TYPES)
    few = make_part_set(np.random.default_rng(5), 3)
    assert len({p.name for p in few}) == 3
    again = make_part_set(np.random.default_rng(3), 8)
    assert [p.name for p in again] == [p.name for p in parts]
    for a, b in zip(parts, again, strict=True):
        np.testing.assert_array_equal(a.mesh.vertices, b.mesh.vertices)


def test_explicit_sizes_are_used():
    part = make_slotted_plate(np.random.default_rng(0), size_x=120.0, size_y=60.0, thickness=5.0)
    np.testing.assert_allclose(np.ptp(part.mesh.vertices, axis=0), [120.0, 60.0, 5.0], atol=1e-4)
    tube = make_tube(np.random.default_rng(0), length=80.0, outer_diameter=40.0, wall=3.0)
    np.testing.assert_allclose(np.ptp(tube.mesh.vertices, axis=0), [40.0, 40.0, 80.0], atol=1e-4)
    carrier = make_carrier(np.random.default_rng(0), size=(300.0, 200.0, 30.0))
    np.testing.assert_allclose(np.ptp(carrier.mesh.vertices, axis=0), [300.0, 200.0, 30.0], atol=1e-4)


@pytest.mark.parametrize(
    "call",
    [
        lambda rng: make_hex_part(rng, kind="wing"),
        lambda rng: make_hex_part(rng, across_corners=20.0, bore_diameter=19.0),
        lambda rng: make_flange(rng, outer_diameter=50.0, bore_diameter=60.0),
        lambda rng: make_tube(rng, outer_diameter=20.0, wall=12.0),
        lambda rng: make_shaft(rng, diameter=10.0, step_diameter=12.0),
        lambda rng: make_slotted_plate(rng, size_x=60.0, size_y=60.0),
        lambda rng: make_bracket(rng, leg_x=20.0, leg_z=14.0),
        lambda rng: make_carrier(rng, size=(200.0, 250.0, 30.0)),
    ],
)
def test_impossible_sizes_raise(call):
    with pytest.raises(ValueError):
        call(np.random.default_rng(0))
