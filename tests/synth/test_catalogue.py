"""The T-LESS layout's catalogue: 30 fixed objects in families of one part type at several sizes."""

from __future__ import annotations

import numpy as np
import pytest

from bop_cender.synth.catalogue import DESIGNS, FAMILIES, N_OBJECTS, SCALE_STEP, catalogue_parts, family_parts, scaled
from bop_cender.synth.parts import PART_TYPES
from bop_cender.synth.write_tless import TABLE_ID, TLESS_CATALOGUE_SEED, tless_models


@pytest.fixture(scope="module")
def catalogue():
    return tless_models(TLESS_CATALOGUE_SEED)


def extents(part) -> np.ndarray:
    return np.ptp(part.mesh.vertices, axis=0)


def test_thirty_objects_of_every_part_type_and_the_table(catalogue):
    assert N_OBJECTS == 30
    assert sorted(catalogue) == [TABLE_ID, *range(1, 31)]
    assert catalogue[TABLE_ID].name == "carrier"
    parts = [catalogue[i] for i in range(1, 31)]
    assert {p.name for p in parts} == set(PART_TYPES)
    for p in parts:  # T-LESS-like sizes: every part between 20 and 150 mm
        assert 20.0 <= extents(p).max() <= 150.0 and p.mesh.is_watertight


def test_families_are_one_type_at_several_sizes_with_the_same_proportions(catalogue):
    """Similar-looking parts of different sizes, as in T-LESS: consecutive ids, the same shape scaled."""
    obj_id = 1
    for index, family in enumerate(FAMILIES):
        members = [catalogue[obj_id + k] for k in range(family.sizes)]
        obj_id += family.sizes
        assert 2 <= family.sizes <= 4
        assert {m.name for m in members} == {family.part_type}
        assert [m.params["family"] for m in members] == [index] * family.sizes
        assert [len(m.mesh.faces) for m in members] == [len(members[0].mesh.faces)] * family.sizes  # same topology
        for k, m in enumerate(members):
            # Every extent scaled by the same factor (to the 0.1 mm the sizes are rounded to, and the makers'
            # own 0.1 mm rounding of holes and bends).
            np.testing.assert_allclose(extents(m), extents(members[0]) * SCALE_STEP**k, atol=0.35)
            assert m.params["scale"] == pytest.approx(SCALE_STEP**k, abs=1e-4)
        sizes = [extents(m).max() for m in members]
        assert all(a > b * 1.2 for a, b in zip(sizes, sizes[1:], strict=False))  # told apart by size
    assert obj_id == 31
    assert max(f.sizes for f in FAMILIES) >= 3


def test_fixed_by_the_catalogue_seed(catalogue):
    again = tless_models(TLESS_CATALOGUE_SEED)
    for obj_id, part in catalogue.items():
        np.testing.assert_array_equal(part.mesh.vertices, again[obj_id].mesh.vertices)
        np.testing.assert_array_equal(part.mesh.faces, again[obj_id].mesh.faces)
    other = catalogue_parts(TLESS_CATALOGUE_SEED + 1)
    assert [p.name for p in other.values()] == [catalogue[i].name for i in range(1, 31)]  # the same families
    assert all(not np.allclose(extents(other[i]), extents(catalogue[i])) for i in range(1, 31))  # other sizes


def test_a_degenerate_design_is_drawn_again():
    """Catalogue seed 15's first flange-with-hub design has degenerate boolean faces; the family still builds."""
    index = next(i for i, f in enumerate(FAMILIES) if f.part_type == "flange" and f.look == 0)
    first = DESIGNS["flange"](np.random.default_rng([15, 7, index, 0]), 0)
    with pytest.raises(RuntimeError, match="degenerate"):
        for k in range(FAMILIES[index].sizes):
            PART_TYPES["flange"](np.random.default_rng([15, 8, index, 0]), **scaled(first, SCALE_STEP**k))
    members = family_parts(15, index)
    assert len(members) == FAMILIES[index].sizes and all(m.mesh.is_watertight for m in members)


def test_scaled_scales_lengths_and_keeps_counts():
    design = {"length": 100.04, "n_holes": 6, "kind": "nut"}
    assert scaled(design, 0.8) == {"length": 80.0, "n_holes": 6, "kind": "nut"}
