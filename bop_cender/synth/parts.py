"""Procedural DIMO-like industrial metal parts, each with its exact BOP symmetry group.

DIMO's six part shapes cannot be downloaded here, so synthetic datasets are built from parts like
them: an L-bracket, a flange, a hex nut or bar, a shaft, a slotted plate and a tube, plus a carrier
tray they rest on (DIMO carriers have ids >= 100). Every maker draws its sizes from a type-specific
range with an explicit ``numpy.random.Generator`` (same seed, same mesh), builds the solid with
manifold3d (2D cross-sections extruded, then 3D booleans), so the mesh is watertight and oriented
outwards, and centres it so that its 3D bounding-box centre is the origin (BOP: "model origin at
the 3D bbox centre"). Symmetry axes are the model z axis wherever the shape allows.

Symmetries follow BOP's ``models_info.json`` convention and list the TRUE proper-rotation group of
the shape without the identity: an n-fold + flip part lists its n - 1 rotations about z and its n
half-turns about axes in the xy plane (2n - 1 entries); a continuous + flip part lists the
continuous z axis and the single half-turn about x (BOP combines them into all the others).

Tessellation is chosen so the discretised surface has the same group as the ideal one: every
circle's segment count is a multiple of the fold count (and of 4, so the bbox centre lies on the
axis) with a vertex on the x axis; continuous parts use 64 segments, so a vertex rotated by any
angle stays within r (1 - cos(pi / 64)) = 0.0012 r of the surface (< 1e-3 of the diameter).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import manifold3d as mf
import numpy as np
import trimesh

from bop_cender.geometry.symmetry import ContinuousSymmetry

#: Continuous surfaces: segments per full circle (see the module docstring for the error bound).
ROUND_SEGMENTS = 64
#: Small holes (bolt holes, bracket holes): segments per full circle.
HOLE_SEGMENTS = 32
#: DIMO convention: model ids >= 100 are carriers (occluders, never pose targets).
#: Rotation by pi about the model x axis: the "flip" of parts symmetric about their mid-plane.
FLIP_X = np.diag([1.0, -1.0, -1.0])
Z_AXIS = ContinuousSymmetry(axis=(0.0, 0.0, 1.0), offset=(0.0, 0.0, 0.0))

ParamValue = float | int | str | bool


@dataclass
class Part:
    """One procedural part: its mesh (mm, bbox centre at the origin) and BOP symmetries.

    Attributes:
        name: the part type (a key of :data:`PART_TYPES`, or ``"carrier"``).
        mesh: watertight, outward-oriented triangle mesh, ``vertices (N, 3)`` mm.
        symmetries_discrete: non-identity discrete symmetries, flattened row-major 4x4 (mm).
        symmetries_continuous: continuous rotational symmetries (axis, offset).
        params: the sizes the maker drew or was given (mm, counts), for reports and debugging.
    """

    name: str
    mesh: trimesh.Trimesh
    symmetries_discrete: list[list[float]]
    symmetries_continuous: list[ContinuousSymmetry]
    params: dict[str, ParamValue] = field(default_factory=dict)


# --------------------------------------------------------------------------- part makers


def make_bracket(
    rng: np.random.Generator,
    leg_x: float | None = None,
    leg_z: float | None = None,
    width: float | None = None,
    thickness: float | None = None,
    holes_per_leg: int | None = None,
    equal_legs: bool = False,
) -> Part:
    """Bent sheet-metal L-bracket: a horizontal leg along +x and a vertical leg along +z, holes in both.

    Default sizes are of the order of 80 x 50 x 56 mm with 4 holes (~600 faces). Legs of unequal
    length make the part asymmetric (no proper rotation maps it onto itself: the y mirror is not a
    rotation). With ``equal_legs`` the two legs and their hole patterns match and the part has one
    true 2-fold axis, the diagonal (1, 0, 1) / sqrt(2): ``(x, y, z) -> (z, -y, x)``.
    """
    leg_x = _draw(rng, leg_x, 45.0, 100.0)
    if equal_legs:
        leg_z = leg_x
    elif leg_z is None:
        leg_z = _draw(rng, None, 30.0, leg_x - 8.0) if rng.random() < 0.7 else _draw(rng, None, leg_x + 8.0, 110.0)
    width = _draw(rng, width, 25.0, 60.0)
    thickness = _draw(rng, thickness, 3.0, 6.0)
    holes_per_leg = int(rng.integers(1, 3)) if holes_per_leg is None else holes_per_leg
    bend = round(thickness * rng.uniform(0.5, 1.5), 1)
    outer = bend + thickness
    flat = min(leg_x, leg_z) - outer
    if flat < 12.0 or width < 12.0 or holes_per_leg not in (1, 2):
        raise ValueError("bracket too small for its holes: legs must exceed bend + thickness + 12 mm")
    hole_r = round(min(flat, width / holes_per_leg) * rng.uniform(0.12, 0.2), 1)
    ys = [0.0] if holes_per_leg == 1 else [-width / 4, width / 4]
    hole_at = outer + flat * 0.55  # same distance from the bend on both legs
    # L profile in the (x, z) plane, extruded along y.
    arc = np.linspace(math.pi, 1.5 * math.pi, 9)
    c = np.array([outer, outer])
    outer_arc = c + outer * np.c_[np.cos(arc), np.sin(arc)]
    inner_arc = (c + bend * np.c_[np.cos(arc), np.sin(arc)])[::-1]
    profile = np.vstack([[[leg_x, 0.0], [leg_x, thickness]], inner_arc, [[thickness, leg_z], [0.0, leg_z]], outer_arc])
    body = _extrude(mf.CrossSection([_ccw(profile)]), width).transform(_frame([1, 0, 0], [0, 0, 1], [0, -1, 0]))
    through = 2 * thickness + 2.0
    for y in ys:
        hx = _extrude(mf.CrossSection([_circle(hole_r, HOLE_SEGMENTS, (hole_at, y))]), through)
        hz = _extrude(mf.CrossSection([_circle(hole_r, HOLE_SEGMENTS, (-y, hole_at))]), through)
        body = body - hx - hz.transform(_frame([0, 1, 0], [0, 0, 1], [1, 0, 0]))
    # Equal legs: the half-turn about the diagonal (1, 0, 1) / sqrt(2) swaps them; otherwise no symmetry.
    sym = [_flat(np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]]))] if leg_x == leg_z else []
    params = dict(leg_x=leg_x, leg_z=leg_z, width=width, thickness=thickness, bend_radius=bend)
    params.update(holes=2 * len(ys), hole_radius=hole_r)
    return _part("bracket", body, sym, [], params)


def make_flange(
    rng: np.random.Generator,
    outer_diameter: float | None = None,
    thickness: float | None = None,
    n_holes: int | None = None,
    bore_diameter: float | None = None,
    hub_height: float | None = None,
) -> Part:
    """Disc with a central bore, ``n_holes`` bolt holes on a circle and an optional hub on both faces.

    The group is n-fold about z plus n half-turns about in-plane axes (the flange is symmetric about
    its mid-plane): 2n - 1 discrete entries.
    """
    od = _draw(rng, outer_diameter, 40.0, 150.0)
    t = _draw(rng, thickness, 4.0, max(4.5, min(20.0, od * 0.15)))
    n = int(rng.integers(3, 9)) if n_holes is None else int(n_holes)
    bore = _draw(rng, bore_diameter, od * 0.2, od * 0.35)
    hub_h = (_draw(rng, None, 2.0, t) if rng.random() < 0.5 else 0.0) if hub_height is None else hub_height
    hub_d = round(bore + (od - bore) * 0.3, 1)
    pitch_r = (od + hub_d) / 4
    hole_r = round(min((od - hub_d) / 4, pitch_r * math.sin(math.pi / max(n, 2)) / 1.5) * rng.uniform(0.35, 0.55), 1)
    if n < 2 or not 0 < bore < hub_d < od or hole_r <= 0:
        raise ValueError(f"flange: {n} holes do not fit between the hub and the rim of a {od} mm disc")
    outer = _circle(od / 2, _segments(ROUND_SEGMENTS, math.lcm(n, 4)))
    holes = [
        _circle(hole_r, HOLE_SEGMENTS, pitch_r * np.array([math.cos(a), math.sin(a)]), phase=a)
        for a in 2 * math.pi * np.arange(n) / n
    ]
    body = _extrude(mf.CrossSection([outer]) - mf.CrossSection(holes), t)
    if hub_h > 0:
        body = body + _extrude(mf.CrossSection([_circle(hub_d / 2, _segments(48, math.lcm(n, 4)))]), t + 2 * hub_h)
    body = body - _extrude(mf.CrossSection([_circle(bore / 2, _segments(48, math.lcm(n, 4)))]), t + 2 * hub_h + 2)
    params = dict(outer_diameter=od, thickness=t, n_holes=n, bore_diameter=bore, hub_height=hub_h, hole_radius=hole_r)
    return _part("flange", body, dihedral_z(n), [], params)


def make_hex_part(
    rng: np.random.Generator,
    kind: str | None = None,
    across_corners: float | None = None,
    length: float | None = None,
    bore_diameter: float | None = None,
) -> Part:
    """Hex nut (short, chamfered on both faces) or hex bar (long) with a round bore along z.

    Corners of the hexagon lie on the x axis. Group: 6-fold about z plus 6 half-turns about the
    in-plane axes at k * 30 deg, i.e. 11 discrete entries.
    """
    kind = str(rng.choice(["nut", "bar"])) if kind is None else kind
    if kind not in ("nut", "bar"):
        raise ValueError(f"hex part kind must be 'nut' or 'bar', got {kind!r}")
    ac = _draw(rng, across_corners, 20.0, 60.0) if kind == "nut" else _draw(rng, across_corners, 15.0, 40.0)
    length = _draw(rng, length, ac * 0.35, ac * 0.6) if kind == "nut" else _draw(rng, length, 40.0, 150.0)
    r = ac / 2
    bore = _draw(rng, bore_diameter, r * 0.7, r * 1.1)
    if not 0 < bore < r * math.sqrt(3) - 2.0:
        raise ValueError(f"hex part: bore {bore} mm leaves no wall inside across-flats {r * math.sqrt(3):.1f} mm")
    hexagon = _circle(r, 6)
    body = _extrude(mf.CrossSection([hexagon]) - mf.CrossSection([_circle(bore / 2, 48)]), length)
    if kind == "nut":  # 30 deg chamfer starting at 0.95 x across-flats on both faces
        slope = 1.0 / math.tan(math.radians(30.0))
        r0 = 0.95 * r * math.sqrt(3) / 2
        ring = _circle(1.0, 72, phase=math.pi / 72)  # no cone edge through a hexagon corner; keeps the group
        h = length + 2.0
        r_low = r0 - slope * 1.0
        cone = mf.Manifold.extrude(mf.CrossSection([ring * r_low]), h, scale_top=((r_low + slope * h) / r_low,) * 2)
        cone = cone.translate([0.0, 0.0, -h / 2])
        body = body ^ cone ^ cone.transform(_frame([1, 0, 0], [0, -1, 0], [0, 0, -1]))
    params = dict(kind=kind, across_corners=ac, length=length, bore_diameter=bore)
    return _part("hex_part", body, dihedral_z(6), [], params)


def make_shaft(
    rng: np.random.Generator,
    length: float | None = None,
    diameter: float | None = None,
    step_diameter: float | None = None,
    step_length: float | None = None,
) -> Part:
    """Cylindrical shaft along z, optionally turned down to a smaller diameter at both ends.

    The steps are equal at both ends so the half-turn about x is a symmetry: continuous about z +
    flip. ``step_diameter=0`` gives a plain cylinder.
    """
    length = _draw(rng, length, 40.0, 150.0)
    d = _draw(rng, diameter, 8.0, min(40.0, length * 0.6))
    if step_diameter is None:
        step_diameter = round(d * rng.uniform(0.55, 0.85), 1) if rng.random() < 0.7 else 0.0
    step_length = _draw(rng, step_length, length * 0.1, length * 0.25)
    ring = _circle(1.0, ROUND_SEGMENTS)
    if step_diameter > 0:
        if not step_diameter < d or not 0 < step_length < length / 2:
            raise ValueError("shaft: steps must be thinner than the body and shorter than half the length")
        body = _extrude(mf.CrossSection([ring * (d / 2)]), length - 2 * step_length)
        body = body + _extrude(mf.CrossSection([ring * (step_diameter / 2)]), length)
    else:
        body = _extrude(mf.CrossSection([ring * (d / 2)]), length)
        step_length = 0.0
    params = dict(length=length, diameter=d, step_diameter=step_diameter, step_length=step_length)
    return _part("shaft", body, [_flat(FLIP_X)], [Z_AXIS], params)


def make_slotted_plate(
    rng: np.random.Generator,
    size_x: float | None = None,
    size_y: float | None = None,
    thickness: float | None = None,
    rows: int | None = None,
    slots_per_row: int | None = None,
) -> Part:
    """Rectangular plate (rounded corners) with rows of slots along x and four corner holes.

    The pattern is mirror-symmetric in x and y and the plate is longer than wide (by >= 10 mm),
    so the group is exactly 2-fold x 2-fold: half-turns about z, x and y (3 discrete entries).
    """
    sx = _draw(rng, size_x, 60.0, 150.0)
    sy = _draw(rng, size_y, 30.0, sx - 10.0)
    t = _draw(rng, thickness, 3.0, 10.0)
    rows = int(rng.integers(1, 3)) if rows is None else rows
    k = int(rng.integers(1, 4)) if slots_per_row is None else slots_per_row
    if sx < sy + 10.0 or rows not in (1, 2) or k < 1:
        raise ValueError("slotted plate: size_x must exceed size_y by 10 mm; 1-2 rows of >= 1 slot")
    margin = round(min(sx, sy) * 0.12, 1)
    hole_r = round(margin * 0.45, 1)
    corner_r = round(margin * 0.8, 1)
    inner_x, inner_y = sx - 4 * margin, sy - 2 * margin
    pitch_x = inner_x / k
    slot_w = round(min(inner_y / (2 * rows), pitch_x * 0.4) * rng.uniform(0.6, 0.9), 1)
    slot_l = round(pitch_x * rng.uniform(0.5, 0.8), 1)
    ys = [0.0] if rows == 1 else [-inner_y / 4, inner_y / 4]
    xs = (np.arange(k) - (k - 1) / 2) * pitch_x
    cuts = [_stadium(slot_l, slot_w, (x, y)) for x in xs for y in ys]
    cuts += [
        _circle(hole_r, HOLE_SEGMENTS, (ex * (sx / 2 - margin), ey * (sy / 2 - margin)))
        for ex in (-1, 1)
        for ey in (-1, 1)
    ]
    body = _extrude(mf.CrossSection([_rounded_rect(sx, sy, corner_r)]) - mf.CrossSection(cuts), t)
    params = dict(size_x=sx, size_y=sy, thickness=t, rows=rows, slots_per_row=k, slot_length=slot_l, slot_width=slot_w)
    return _part("slotted_plate", body, dihedral_z(2), [], params)


def make_tube(
    rng: np.random.Generator,
    length: float | None = None,
    outer_diameter: float | None = None,
    wall: float | None = None,
) -> Part:
    """Hollow cylinder along z: continuous about z + flip."""
    length = _draw(rng, length, 20.0, 150.0)
    od = _draw(rng, outer_diameter, 15.0, min(100.0, max(20.0, length * 1.5)))
    wall = _draw(rng, wall, 1.5, od * 0.2)
    if not 0 < wall < od / 2:
        raise ValueError(f"tube: wall {wall} mm must be positive and thinner than the radius {od / 2} mm")
    ring = _circle(1.0, ROUND_SEGMENTS)
    body = _extrude(mf.CrossSection([ring * (od / 2)]) - mf.CrossSection([ring * (od / 2 - wall)]), length)
    return _part("tube", body, [_flat(FLIP_X)], [Z_AXIS], dict(length=length, outer_diameter=od, wall=wall))


def make_carrier(rng: np.random.Generator, size: tuple[float, float, float] | None = None) -> Part:
    """Carrier tray the parts rest on: rounded box (x > y, z up) with one pocket open at the top.

    Its true group is the half-turn about z (the open top rules out the flips). ``size`` is
    ``(x, y, z)`` mm; drawn from 220-320 x 150-210 x 20-40 mm when not given.
    """
    if size is None:
        size = (_draw(rng, None, 220.0, 320.0), _draw(rng, None, 150.0, 210.0), _draw(rng, None, 20.0, 40.0))
    sx, sy, sz = (float(v) for v in size)
    rim = round(min(sx, sy) * rng.uniform(0.05, 0.08), 1)
    floor = round(sz * rng.uniform(0.25, 0.4), 1)
    if sx <= sy or min(sx, sy) <= 4 * rim or sz <= floor:
        raise ValueError(f"carrier size {size}: need x > y and room for the rim and floor")
    box = _extrude(mf.CrossSection([_rounded_rect(sx, sy, 2 * rim)]), sz)
    pocket = _extrude(mf.CrossSection([_rounded_rect(sx - 2 * rim, sy - 2 * rim, rim)]), sz).translate([0, 0, floor])
    params = dict(size_x=sx, size_y=sy, size_z=sz, rim=rim, floor=floor)
    return _part("carrier", box - pocket, cyclic_z(2), [], params)


PART_TYPES: dict[str, Callable[..., Part]] = {
    "bracket": make_bracket,
    "flange": make_flange,
    "hex_part": make_hex_part,
    "shaft": make_shaft,
    "slotted_plate": make_slotted_plate,
    "tube": make_tube,
}


def make_part_set(rng: np.random.Generator, n: int) -> list[Part]:
    """``n`` parts with sizes drawn by ``rng``: every type at least once when ``n >= len(PART_TYPES)``.

    With fewer, ``n`` distinct types. The order of the types is shuffled.
    """
    names = list(PART_TYPES)
    if n <= len(names):
        chosen = list(rng.choice(names, size=n, replace=False))
    else:
        chosen = names + list(rng.choice(names, size=n - len(names)))
        chosen = [chosen[i] for i in rng.permutation(n)]
    return [PART_TYPES[str(name)](rng) for name in chosen]


# --------------------------------------------------------------------------- symmetry groups


def cyclic_z(n: int) -> list[list[float]]:
    """Non-identity rotations of the n-fold group about z: ``Rz(2 pi k / n)``, k = 1..n-1, flattened 4x4."""
    return [_flat(_rot_z(2 * math.pi * k / n)) for k in range(1, n)]


def dihedral_z(n: int) -> list[list[float]]:
    """Non-identity elements of the n-fold + flip group: :func:`cyclic_z` plus ``Rz(2 pi k / n) Rx(pi)``."""
    return cyclic_z(n) + [_flat(_rot_z(2 * math.pi * k / n) @ FLIP_X) for k in range(n)]


def _rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _flat(R: np.ndarray, t: np.ndarray | None = None) -> list[float]:
    """Row-major 16 floats of the 4x4 ``[R t; 0 1]``; round-off below 1e-12 snapped to 0."""
    T = np.eye(4)
    T[:3, :3] = R
    if t is not None:
        T[:3, 3] = t
    T[np.abs(T) < 1e-12] = 0.0
    return [float(v) for v in T.ravel()]


# --------------------------------------------------------------------------- geometry helpers


def _draw(rng: np.random.Generator, value: float | None, lo: float, hi: float) -> float:
    """``value`` if given, else uniform in [lo, hi] rounded to 0.1 mm (readable sizes)."""
    return float(value) if value is not None else round(float(rng.uniform(lo, max(lo, hi))), 1)


def _segments(target: int, multiple: int) -> int:
    """The multiple of ``multiple`` nearest to ``target`` (at least one multiple)."""
    return multiple * max(1, round(target / multiple))


def _circle(r: float, n: int, center: tuple[float, float] | np.ndarray = (0.0, 0.0), phase: float = 0.0) -> np.ndarray:
    """Regular n-gon ``(n, 2)`` counter-clockwise, first vertex at angle ``phase`` from ``center``."""
    a = phase + 2 * math.pi * np.arange(n) / n
    return np.asarray(center, dtype=np.float64) + r * np.c_[np.cos(a), np.sin(a)]


def _stadium(length: float, width: float, center: tuple[float, float]) -> np.ndarray:
    """Slot outline along x ``(M, 2)``: two half-circles of diameter ``width``, ``length`` end to end."""
    a = np.linspace(-math.pi / 2, math.pi / 2, HOLE_SEGMENTS // 2 + 1)
    cap = (width / 2) * np.c_[np.cos(a), np.sin(a)]
    half = length / 2 - width / 2
    return np.asarray(center) + np.vstack([cap + [half, 0.0], -cap - [half, 0.0]])


def _rounded_rect(sx: float, sy: float, r: float) -> np.ndarray:
    """Rectangle ``sx x sy`` centred at the origin with corner radius ``r``, ``(M, 2)`` counter-clockwise."""
    a = np.linspace(0.0, math.pi / 2, 7)
    quarter = r * np.c_[np.cos(a), np.sin(a)]
    corners = []
    for k, (ex, ey) in enumerate([(1, 1), (-1, 1), (-1, -1), (1, -1)]):
        rot = _rot_z(k * math.pi / 2)[:2, :2]
        corners.append(quarter @ rot.T + [ex * (sx / 2 - r), ey * (sy / 2 - r)])
    return np.vstack(corners)


def _ccw(poly: np.ndarray) -> np.ndarray:
    """``poly (M, 2)`` reordered counter-clockwise (positive shoelace area)."""
    x, y = poly[:, 0], poly[:, 1]
    area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    return poly if area > 0 else poly[::-1]


def _extrude(section: mf.CrossSection, height: float) -> mf.Manifold:
    """Prism of ``section`` along z, centred on z = 0."""
    return mf.Manifold.extrude(section, height).translate([0.0, 0.0, -height / 2])


def _frame(x_to: list[float], y_to: list[float], z_to: list[float]) -> np.ndarray:
    """3x4 affine (no translation) sending the local x, y, z axes to the given directions (det +1)."""
    R = np.array([x_to, y_to, z_to], dtype=np.float64).T
    if not np.isclose(np.linalg.det(R), 1.0):
        raise ValueError("frame must be a proper rotation")
    return np.c_[R, np.zeros(3)]


def _part(
    name: str,
    solid: mf.Manifold,
    discrete: list[list[float]],
    continuous: list[ContinuousSymmetry],
    params: dict[str, ParamValue],
) -> Part:
    """Manifold solid -> centred :class:`Part`, checking it is a closed, outward, non-degenerate mesh."""
    out = solid.to_mesh64()
    vertices = np.asarray(out.vert_properties, dtype=np.float64)[:, :3]
    faces = np.asarray(out.tri_verts, dtype=np.int64)
    vertices = vertices - (vertices.min(axis=0) + vertices.max(axis=0)) / 2
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    scale = float(np.ptp(vertices, axis=0).max())
    if not (mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0):
        raise RuntimeError(f"{name}: boolean result is not a closed outward mesh (params {params})")
    if mesh.area_faces.min() < 1e-9 * scale**2:
        raise RuntimeError(f"{name}: degenerate faces in the boolean result (params {params})")
    return Part(name=name, mesh=mesh, symmetries_discrete=discrete, symmetries_continuous=continuous, params=params)
