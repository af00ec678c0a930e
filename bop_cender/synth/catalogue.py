"""The T-LESS layout's object catalogue: 30 parts in families of one part type drawn at several sizes.

Real T-LESS has 30 texture-less industrial objects, and what makes it hard is that many come in
families of similar-looking parts of different sizes (the pose network must tell them apart by scale and
small details). The synthetic catalogue copies that structure with our procedural part types
(:mod:`bop_cender.synth.parts`): :data:`FAMILIES` lists 12 families, two per part type (two looks of the
type: a stepped and a plain shaft, a nut and a bar, ...), of 2 to 4 members, ids given family by family
(1..30, as T-LESS numbers similar objects consecutively).

A family's design (its largest member's dimensions, hole counts, ratios) is drawn from the catalogue
seed; member ``k`` is the design scaled by ``SCALE_STEP ** k`` (every length, so the proportions are
the same). The makers also draw a few details themselves (bend radius, hole radius, slot sizes, as
fractions of the given sizes): every member of a family gets a generator seeded the same way, so those
fractions, hence the proportions, match too.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bop_cender.synth.parts import PART_TYPES, ParamValue, Part

#: Consecutive members of a family differ by this factor in every length (T-LESS's look-alikes differ by
#: 15-30 %; 0.8 keeps even a 4-member family's smallest part above 40 mm).
SCALE_STEP = 0.8


@dataclass(frozen=True)
class Family:
    """One family of the catalogue: a part type, which of its two looks, and how many sizes.

    Attributes:
        part_type: a key of :data:`~bop_cender.synth.parts.PART_TYPES`.
        look: 0 or 1, the design drawn (see :data:`DESIGNS`).
        sizes: members (2-4), the largest first.
    """

    part_type: str
    look: int
    sizes: int


#: The 12 families in id order: 30 objects, every part type with two looks.
FAMILIES: tuple[Family, ...] = (
    Family("shaft", 0, 4),  # stepped shafts: ids 1-4
    Family("shaft", 1, 2),  # plain cylinders: 5-6
    Family("tube", 0, 3),  # long tubes: 7-9
    Family("tube", 1, 2),  # short rings: 10-11
    Family("flange", 0, 3),  # flanges with a hub: 12-14
    Family("flange", 1, 2),  # flat flanges: 15-16
    Family("hex_part", 0, 2),  # hex nuts: 17-18
    Family("hex_part", 1, 2),  # hex bars: 19-20
    Family("slotted_plate", 0, 3),  # one row of slots: 21-23
    Family("slotted_plate", 1, 2),  # two rows of slots: 24-25
    Family("bracket", 0, 3),  # unequal legs (asymmetric): 26-28
    Family("bracket", 1, 2),  # equal legs (one 2-fold axis): 29-30
)
N_OBJECTS = sum(f.sizes for f in FAMILIES)


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _shaft(rng: np.random.Generator, look: int) -> dict[str, ParamValue]:
    length = _u(rng, 95.0, 150.0) if look == 0 else _u(rng, 60.0, 130.0)
    d = length * _u(rng, 0.14, 0.26)
    if look == 1:
        return dict(length=length, diameter=d, step_diameter=0.0, step_length=0.0)
    return dict(
        length=length, diameter=d, step_diameter=d * _u(rng, 0.55, 0.8), step_length=length * _u(rng, 0.1, 0.25)
    )


def _tube(rng: np.random.Generator, look: int) -> dict[str, ParamValue]:
    if look == 0:  # longer than wide
        length = _u(rng, 90.0, 145.0)
        od = length * _u(rng, 0.3, 0.5)
        return dict(length=length, outer_diameter=od, wall=od * _u(rng, 0.08, 0.15))
    od = _u(rng, 60.0, 100.0)  # a ring: shorter than wide
    return dict(length=od * _u(rng, 0.3, 0.6), outer_diameter=od, wall=od * _u(rng, 0.07, 0.12))


def _flange(rng: np.random.Generator, look: int) -> dict[str, ParamValue]:
    od = _u(rng, 95.0, 150.0)
    t = od * _u(rng, 0.07, 0.12)
    design: dict[str, ParamValue] = dict(outer_diameter=od, thickness=t, n_holes=int(rng.integers(3, 9)))
    design.update(bore_diameter=od * _u(rng, 0.2, 0.35), hub_height=t * _u(rng, 0.4, 0.9) if look == 0 else 0.0)
    return design


def _hex_part(rng: np.random.Generator, look: int) -> dict[str, ParamValue]:
    if look == 0:
        ac = _u(rng, 40.0, 60.0)
        return dict(
            kind="nut", across_corners=ac, length=ac * _u(rng, 0.35, 0.6), bore_diameter=ac / 2 * _u(rng, 0.7, 1.1)
        )
    ac = _u(rng, 22.0, 40.0)
    return dict(kind="bar", across_corners=ac, length=_u(rng, 80.0, 150.0), bore_diameter=ac / 2 * _u(rng, 0.5, 0.9))


def _slotted_plate(rng: np.random.Generator, look: int) -> dict[str, ParamValue]:
    sx = _u(rng, 100.0, 150.0)
    design: dict[str, ParamValue] = dict(size_x=sx, size_y=sx * _u(rng, 0.4, 0.65), thickness=sx * _u(rng, 0.04, 0.07))
    return design | dict(rows=1 + look, slots_per_row=int(rng.integers(1, 4)))


def _bracket(rng: np.random.Generator, look: int) -> dict[str, ParamValue]:
    leg_x = _u(rng, 80.0, 110.0) if look == 0 else _u(rng, 70.0, 100.0)
    design: dict[str, ParamValue] = dict(leg_x=leg_x, leg_z=leg_x * _u(rng, 0.55, 0.85) if look == 0 else leg_x)
    design.update(width=leg_x * _u(rng, 0.35, 0.6), thickness=leg_x * _u(rng, 0.04, 0.07))
    return design | dict(holes_per_leg=int(rng.integers(1, 3)))


#: Per part type, the design of a family's largest member for each look: explicit arguments of the maker
#: (floats are lengths in mm and are scaled; ints and strings are counts and kinds, kept).
DESIGNS: dict[str, Callable[[np.random.Generator, int], dict[str, ParamValue]]] = {
    "shaft": _shaft,
    "tube": _tube,
    "flange": _flange,
    "hex_part": _hex_part,
    "slotted_plate": _slotted_plate,
    "bracket": _bracket,
}


def scaled(design: dict[str, ParamValue], scale: float) -> dict[str, ParamValue]:
    """``design`` with every length (float) times ``scale``, rounded to 0.1 mm (readable sizes)."""
    return {k: round(v * scale, 1) if isinstance(v, float) else v for k, v in design.items()}


def catalogue_parts(catalogue_seed: int) -> dict[int, Part]:
    """The catalogue's parts by obj_id (1..:data:`N_OBJECTS`, family by family, largest member first).

    ``Part.params`` also records ``family`` (its index in :data:`FAMILIES`) and ``scale``.
    """
    parts: dict[int, Part] = {}
    for index in range(len(FAMILIES)):
        for part in family_parts(catalogue_seed, index):
            parts[len(parts) + 1] = part
    return parts


def family_parts(catalogue_seed: int, index: int, max_attempts: int = 8) -> list[Part]:
    """The members of family ``index`` of :data:`FAMILIES`, largest first.

    A design whose boolean result is degenerate at one of its sizes (a hole edge landing on a hub edge,
    say: about one family in a few thousand) is drawn again, so that every catalogue seed gives a
    catalogue; the attempt number is part of the generator's seed, so the result is still fixed.
    """
    family = FAMILIES[index]
    for attempt in range(max_attempts):
        design = DESIGNS[family.part_type](np.random.default_rng([catalogue_seed, 7, index, attempt]), family.look)
        members = []
        try:
            for k in range(family.sizes):
                scale = SCALE_STEP**k
                details = np.random.default_rng([catalogue_seed, 8, index, attempt])  # the same for every member
                part = PART_TYPES[family.part_type](details, **scaled(design, scale))
                part.params.update(family=index, scale=round(scale, 4))
                members.append(part)
        except (ValueError, RuntimeError):
            continue
        return members
    raise RuntimeError(f"catalogue seed {catalogue_seed}: family {index} ({family}) failed {max_attempts} designs")
