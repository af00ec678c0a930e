import logging

import numpy as np
import pytest
import trimesh
from scipy.spatial import Delaunay

from bop_cender.geometry.poses import make_pose
from bop_cender.geometry.rotations import axis_angle_to_rotmat
from bop_cender.synth.piles import Placement, build_pile, choose_part_indices, penetration_depth, stable_poses

CARRIER_TOP = 0.0
TOL_MM = 1.0


def _l_shape() -> trimesh.Trimesh:
    a = trimesh.creation.box((80.0, 20.0, 20.0))
    b = trimesh.creation.box((20.0, 20.0, 60.0))
    b.apply_translation((30.0, 0.0, 20.0))
    m = trimesh.boolean.union([a, b], engine="manifold")
    m.apply_translation(-m.bounds.mean(axis=0))  # models are centred at their bbox centre
    return m


MESHES = [
    trimesh.creation.box((60.0, 30.0, 15.0)),
    trimesh.creation.cylinder(12.0, 90.0, sections=32),
    _l_shape(),
    trimesh.creation.cylinder(30.0, 20.0, sections=48),
]
CARRIER = trimesh.creation.box((300.0, 220.0, 20.0))
T_WORLD_CARRIER = make_pose(np.eye(3), [0.0, 0.0, CARRIER_TOP - 10.0])


def _world(meshes, placements: list[Placement]) -> list[trimesh.Trimesh]:
    return [meshes[p.part_index].copy().apply_transform(p.T_world_model) for p in placements]


def _probe_points(mesh: trimesh.Trimesh) -> np.ndarray:
    """Dense surface samples plus vertices (a corner poking into another part is a vertex)."""
    return np.concatenate([mesh.sample(2500, seed=3), mesh.vertices])


def _near(points: np.ndarray, mesh: trimesh.Trimesh, margin: float) -> np.ndarray:
    lo, hi = mesh.bounds
    return points[np.all((points >= lo - margin) & (points <= hi + margin), axis=1)]


@pytest.fixture(scope="module")
def pile() -> tuple[list[Placement], list[trimesh.Trimesh]]:
    placements = build_pile(MESHES, CARRIER, T_WORLD_CARRIER, 8, np.random.default_rng(0))
    return placements, _world(MESHES, placements)


def test_pile_places_all_parts(pile):
    placements, _ = pile
    assert len(placements) == 8
    for p in placements:
        assert p.T_world_model.shape == (4, 4) and p.T_world_model.dtype == np.float64
        np.testing.assert_allclose(p.T_world_model[:3, :3] @ p.T_world_model[:3, :3].T, np.eye(3), atol=1e-9)


def test_no_two_solids_interpenetrate(pile):
    _, world = pile
    assert _worst_penetration([CARRIER.copy().apply_transform(T_WORLD_CARRIER), *world]) <= TOL_MM


def test_every_part_rests_on_something(pile):
    # lowered by a bit more than the tolerance, each part must run into the carrier or another part
    _, world = pile
    solids = [CARRIER.copy().apply_transform(T_WORLD_CARRIER), *world]
    for i, part in enumerate(world, start=1):
        lowered = part.copy().apply_translation((0.0, 0.0, -1.5 * TOL_MM))
        points = _probe_points(lowered)
        hits = 0
        for j, other in enumerate(solids):
            if j == i:
                continue
            hits += int(other.contains(_near(points, other, 0.0)).sum()) if len(_near(points, other, 0.0)) else 0
            other_points = _near(_probe_points(other), lowered, 0.0)
            hits += int(lowered.contains(other_points).sum()) if len(other_points) else 0
        assert hits > 0, f"part {i - 1} floats"


def test_pile_is_dense_stacked_and_overlapping(pile):
    _, world = pile
    lowest = np.array([m.bounds[0, 2] for m in world])
    assert np.isclose(lowest, CARRIER_TOP, atol=1e-6).sum() >= 2  # some lie on the carrier
    assert (lowest > CARRIER_TOP + 5.0).sum() >= 2  # some lie on other parts
    # xy projections overlap: a vertex of one part inside the xy hull of the other
    hulls = [Delaunay(m.vertices[:, :2]) for m in world]
    overlapping = sum(
        np.any(hulls[i].find_simplex(world[j].vertices[:, :2]) >= 0)
        or np.any(hulls[j].find_simplex(world[i].vertices[:, :2]) >= 0)
        for i in range(len(world))
        for j in range(i + 1, len(world))
    )
    assert overlapping >= 4
    # parts touch each other: several pairs within the tolerance
    touching = 0
    for i, a in enumerate(world):
        for b in world[i + 1 :]:
            near = _near(_probe_points(a), b, TOL_MM)
            touching += int(len(near) > 0 and trimesh.proximity.closest_point(b, near)[1].min() <= TOL_MM)
    assert touching >= 3


def _worst_penetration(solids: list[trimesh.Trimesh]) -> float:
    worst = 0.0
    for i, a in enumerate(solids[1:], start=1):
        points = _probe_points(a)
        for j, b in enumerate(solids):
            near = _near(points, b, 0.0) if j != i else np.empty((0, 3))
            if len(near):
                worst = max(worst, float(trimesh.proximity.signed_distance(b, near).max()))  # > 0 inside
    return worst


def test_final_check_catches_edge_edge_contacts():
    # with no edge samples the drop sees only vertex-face contacts, and crossing rods sink into each
    # other edge-on: the containment check must reject those drops, so the pile still does not penetrate
    rod = trimesh.creation.box((120.0, 12.0, 12.0))
    rod.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 4, [1.0, 0.0, 0.0]))
    placements = build_pile(
        [rod], CARRIER, T_WORLD_CARRIER, 10, np.random.default_rng(0), edge_spacing_mm=1000.0, candidates=1
    )
    assert len(placements) == 10
    assert _worst_penetration([CARRIER.copy().apply_transform(T_WORLD_CARRIER), *_world([rod], placements)]) <= TOL_MM


def test_parts_keep_a_stable_resting_orientation():
    # a box rests on a face: one model axis is vertical in every placement
    box = trimesh.creation.box((50.0, 30.0, 12.0))
    placements = build_pile([box], CARRIER, T_WORLD_CARRIER, 6, np.random.default_rng(2))
    assert len(placements) == 6
    for p in placements:
        assert np.max(np.abs(p.T_world_model[2, :3])) == pytest.approx(1.0, abs=1e-9)


def test_drop_lands_exactly_on_the_part_below():
    # all drops at the carrier centre (spread 0): each box lands flush on top of the previous one
    box = trimesh.creation.box((40.0, 40.0, 10.0))
    yaw = make_pose(axis_angle_to_rotmat(np.array([0.0, 0.0, 1.0]), 0.4), [100.0, -50.0, 200.0])
    placements = build_pile([box], CARRIER, yaw, 4, np.random.default_rng(1), spread=0.0)
    world = _world([box], placements)
    np.testing.assert_allclose(world[0].bounds[0, 2], 200.0 + 10.0, atol=1e-6)  # the carrier's top face
    for below, above in zip(world, world[1:], strict=False):
        np.testing.assert_allclose(above.bounds[0, 2], below.bounds[1, 2], atol=1e-6)
    centres = np.array([m.bounds.mean(axis=0)[:2] for m in world])
    np.testing.assert_allclose(centres, np.tile([100.0, -50.0], (4, 1)), atol=1e-6)


def test_pile_is_deterministic_per_seed():
    a = build_pile(MESHES, CARRIER, T_WORLD_CARRIER, 6, np.random.default_rng(5))
    b = build_pile(MESHES, CARRIER, T_WORLD_CARRIER, 6, np.random.default_rng(5))
    c = build_pile(MESHES, CARRIER, T_WORLD_CARRIER, 6, np.random.default_rng(6))
    assert [p.part_index for p in a] == [p.part_index for p in b]
    for pa, pb in zip(a, b, strict=True):
        np.testing.assert_array_equal(pa.T_world_model, pb.T_world_model)
    assert not np.array_equal(a[0].T_world_model, c[0].T_world_model)


def test_compositions_select_meshes():
    rng = np.random.default_rng(3)
    same = choose_part_indices(4, 10, "same", rng)
    assert len(set(same.tolist())) == 1
    mixed = choose_part_indices(4, 40, "mixed", rng)
    assert set(mixed.tolist()) == {0, 1, 2, 3}
    subset = choose_part_indices(4, 20, [1, 3], rng)
    assert set(subset.tolist()) == {1, 3}
    with pytest.raises(ValueError):
        choose_part_indices(4, 3, [4], rng)
    placements = build_pile(MESHES, CARRIER, T_WORLD_CARRIER, 3, np.random.default_rng(0), composition=[2])
    assert [p.part_index for p in placements] == [2, 2, 2]


def test_gives_up_and_says_so(caplog):
    # no drop can satisfy a negative penetration bound: every part is left out, with a warning
    with caplog.at_level(logging.WARNING, logger="bop_cender.synth.piles"):
        placements = build_pile(
            MESHES[:1], CARRIER, T_WORLD_CARRIER, 2, np.random.default_rng(0), max_penetration_mm=-1
        )
    assert placements == []
    assert "placed 0 of 2 parts" in caplog.text


def test_penetration_depth_known_answer():
    box = trimesh.creation.box((20.0, 20.0, 20.0))  # [-10, 10]^3
    assert penetration_depth(box, np.array([[0.0, 0.0, 7.0], [30.0, 0.0, 0.0]])) == pytest.approx(3.0)
    assert penetration_depth(box, np.array([[0.0, 0.0, 12.0]])) == 0.0


def test_stable_poses_rest_on_z0_with_probabilities():
    poses, probs = stable_poses(MESHES[2])
    assert poses.shape[1:] == (4, 4) and probs.shape == (len(poses),)
    assert probs.sum() == pytest.approx(1.0)
    for T in poses:
        assert trimesh.transform_points(MESHES[2].vertices, T)[:, 2].min() == pytest.approx(0.0, abs=1e-9)


def test_pile_of_procedural_parts_in_a_tray():
    parts = pytest.importorskip("bop_cender.synth.parts")
    rng = np.random.default_rng(11)
    meshes = [p.mesh for p in parts.make_part_set(rng, 6)]
    carrier = parts.make_carrier(rng).mesh
    T = make_pose(np.eye(3), [0.0, 0.0, -carrier.bounds[1, 2]])
    placements = build_pile(meshes, carrier, T, 8, rng)
    assert len(placements) == 8
    world = _world(meshes, placements)
    solids = [carrier.copy().apply_transform(T), *world]
    for i, a in enumerate(world, start=1):
        points = a.vertices
        for j, b in enumerate(solids):
            near = _near(points, b, 0.0) if j != i else np.empty((0, 3))
            if len(near):
                assert trimesh.proximity.signed_distance(b, near).max() <= TOL_MM
