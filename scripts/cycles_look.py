"""The look of ``scripts/rerender_cycles.py``: what is drawn per scene, and the Blender (Cycles) scene built from it.

Not a command (the CLI is ``rerender_cycles.py``). The draws (:func:`draw_look`), the support plane
(:func:`support_plane`) and the camera conversion (:func:`blender_camera`) need no Blender; the Blender scene made
from them is ``cycles_scene.py``'s.

Units: the datasets are in millimetres, the Blender scene in metres (``MM``): lights' power and the sky are
physical in Blender's units, so the scene is kept at its real size rather than 1000 times larger.
"""

from __future__ import annotations

import colorsys
import math
from dataclasses import dataclass

import numpy as np

#: metres per millimetre: every length goes into Blender through this.
MM = 1e-3
#: OpenCV camera (x right, y down, z forward) to Blender camera (x right, y up, looking down -z).
CV_TO_BLENDER = np.diag([1.0, -1.0, -1.0, 1.0])
#: K[0, 1] above this (pixels) is a skew Blender's camera cannot make.
MAX_SKEW = 1e-6
#: Blender's camera sensor width (mm); any value works, the lens is scaled to it.
SENSOR_WIDTH = 36.0


class SkewError(ValueError):
    """The intrinsics have a skew term: a Blender camera has none, the image would be sheared against the GT."""


@dataclass(frozen=True)
class Lamp:
    """One area light, placed around the pile's centre in the frame of the support plane (``up`` its normal).

    Attributes:
        kelvin: colour temperature (Blender's blackbody).
        size: edge (rectangle) or diameter (disk), metres.
        disk: a disk rather than a rectangle.
        azimuth, elevation: direction from the pile's centre, radians (elevation from the plane).
        distance: from the pile's centre, metres.
        power: watts (Blender's area-light power).
    """

    kelvin: float
    size: float
    disk: bool
    azimuth: float
    elevation: float
    distance: float
    power: float


@dataclass(frozen=True)
class Look:
    """Everything random about one scene's images; one draw per scene (all its views share it).

    Colours are linear RGB in [0, 1].

    Attributes:
        target_color, target_roughness, target_metallic: the targets' principled BSDF (DIMO: metal, T-LESS: plastic).
        anisotropy, anisotropy_rotation: brushed metal (0: isotropic, rough metal; plastic has 0).
        scratch: strength of a fine noise bump on the targets (machining marks; 0 for none).
        carrier_color, carrier_roughness: the carriers (DIMO ids from 100): painted trays.
        table: the ground plane's procedural texture, one of ``TABLES``.
        table_colors: its two colours ``(2, 3)``.
        table_scale: texture features per metre.
        table_roughness: the plane's roughness.
        sky: a physical sky texture (True) or a coloured gradient (False).
        sky_colors: gradient: ground, horizon and zenith colours ``(3, 3)``; sky: unused.
        sun_elevation, sun_rotation: sky: the sun's direction (radians).
        world_strength: the world's emission strength.
        lamps: one or two area lights.
        exposure: the view transform's exposure (stops).
    """

    target_color: tuple[float, float, float]
    target_roughness: float
    target_metallic: float
    anisotropy: float
    anisotropy_rotation: float
    scratch: float
    carrier_color: tuple[float, float, float]
    carrier_roughness: float
    table: str
    table_colors: tuple[tuple[float, float, float], tuple[float, float, float]]
    table_scale: float
    table_roughness: float
    sky: bool
    sky_colors: tuple[tuple[float, float, float], ...]
    sun_elevation: float
    sun_rotation: float
    world_strength: float
    lamps: tuple[Lamp, ...]
    exposure: float


#: The ground plane's textures, all from Blender's own nodes: wood grain (wave), a checker mat, a marbled stone (noise).
TABLES = ("wood", "checker", "marble")


def draw_look(rng: np.random.Generator, layout: str) -> Look:
    """One scene's look: DIMO's parts metal (brushed or rough), T-LESS's objects grey or coloured plastic."""

    def hsv(h: float, s: float, v: float) -> tuple[float, float, float]:
        return tuple(float(c) ** 2.2 for c in colorsys.hsv_to_rgb(h % 1.0, s, v))  # sRGB-ish to linear

    if layout == "dimo":  # steel, aluminium or a warm/blue-tinted alloy
        brushed = rng.random() < 0.6
        target = hsv(rng.uniform(0.0, 1.0), rng.uniform(0.0, 0.12), rng.uniform(0.78, 0.95))
        roughness = rng.uniform(0.22, 0.38) if brushed else rng.uniform(0.35, 0.55)
        metallic, anisotropy = 1.0, (rng.uniform(0.6, 0.9) if brushed else 0.0)
        scratch = rng.uniform(0.05, 0.15) if brushed else rng.uniform(0.15, 0.35)
    else:  # plastic: mostly grey, sometimes coloured
        coloured = rng.random() < 0.35
        target = hsv(rng.uniform(0.0, 1.0), rng.uniform(0.3, 0.6) if coloured else rng.uniform(0.0, 0.05),
                     rng.uniform(0.45, 0.85))  # fmt: skip
        roughness, metallic, anisotropy, scratch = rng.uniform(0.3, 0.6), 0.0, 0.0, rng.uniform(0.0, 0.05)
    carrier = hsv(rng.uniform(0.0, 1.0), rng.uniform(0.5, 0.85), rng.uniform(0.35, 0.75))
    base_hue = rng.uniform(0.0, 1.0)
    table_colors = (
        hsv(base_hue, rng.uniform(0.1, 0.6), rng.uniform(0.25, 0.6)),
        hsv(base_hue + rng.uniform(-0.1, 0.1), rng.uniform(0.1, 0.6), rng.uniform(0.55, 0.9)),
    )
    table = TABLES[int(rng.integers(len(TABLES)))]
    sky = rng.random() < 0.5
    sky_colors = tuple(hsv(rng.uniform(0.0, 1.0), rng.uniform(0.1, 0.5), rng.uniform(0.3, 0.9)) for _ in range(3))
    n_lamps = int(rng.integers(1, 3))
    lamps = []
    for k in range(n_lamps):
        distance = rng.uniform(0.6, 1.4)
        lamps.append(
            Lamp(
                kelvin=rng.uniform(2700.0, 7500.0),
                size=rng.uniform(0.1, 0.8),
                disk=bool(rng.random() < 0.5),
                azimuth=rng.uniform(0.0, 2 * math.pi),
                elevation=rng.uniform(math.radians(35.0), math.radians(80.0)),
                distance=distance,
                power=rng.uniform(15.0, 35.0) * distance**2 / n_lamps * (1.0 if k == 0 else rng.uniform(0.3, 1.0)),
            )
        )
    return Look(
        target_color=target,
        target_roughness=float(roughness),
        target_metallic=metallic,
        anisotropy=float(anisotropy),
        anisotropy_rotation=float(rng.uniform(0.0, 1.0)),
        scratch=float(scratch),
        carrier_color=carrier,
        carrier_roughness=float(rng.uniform(0.3, 0.75)),
        table=table,
        table_colors=table_colors,
        table_scale=float(rng.uniform(4.0, 20.0)),
        table_roughness=float(rng.uniform(0.4, 0.9)),
        sky=bool(sky),
        sky_colors=sky_colors,
        sun_elevation=float(rng.uniform(math.radians(10.0), math.radians(70.0))),
        sun_rotation=float(rng.uniform(0.0, 2 * math.pi)),
        world_strength=float(rng.uniform(0.15, 0.5)),
        lamps=tuple(lamps),
        exposure=float(rng.uniform(-0.4, 0.4)),
    )


def blender_camera(K: np.ndarray, width: int, height: int) -> dict[str, float]:
    """Blender camera and render settings that make the pinhole ``K (3, 3)`` on a ``width x height`` image.

    The sensor is fitted to the width (``sensor_fit = 'HORIZONTAL'``), so the lens is ``fx`` in sensor units and
    both shifts are fractions of the width; ``fx != fy`` becomes a pixel aspect (Blender's ``ycor = aspy / aspx =
    fx / fy``), which also scales the vertical shift. Both conventions put pixel ``(u, v)``'s centre at
    ``(u + 0.5, v + 0.5)``, so the image centre is ``(width / 2, height / 2)``.

    Raises:
        SkewError: ``K[0, 1]`` is not 0.
    """
    K = np.asarray(K, dtype=np.float64)
    if abs(K[0, 1]) > MAX_SKEW:
        raise SkewError(f"cam_K has skew {K[0, 1]:g} (K[0][1]); Blender's camera has none")
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    aspect_x, aspect_y = (fy / fx, 1.0) if fy >= fx else (1.0, fx / fy)
    ycor = aspect_y / aspect_x
    return {
        "lens": fx * SENSOR_WIDTH / width,
        "sensor_width": SENSOR_WIDTH,
        "shift_x": (width / 2.0 - cx) / width,
        "shift_y": (cy - height / 2.0) * ycor / width,
        "pixel_aspect_x": aspect_x,
        "pixel_aspect_y": aspect_y,
    }


def support_plane(points: np.ndarray, eyes: np.ndarray, margin: float = 0.5) -> tuple[np.ndarray, np.ndarray] | None:
    """The plane the pile rests on: the largest face of the points' convex hull that every camera sees from behind.

    Args:
        points: ``(N, 3)`` the GT objects' vertices in the world, mm.
        eyes: ``(V, 3)`` camera centres in the world, mm.
        margin: the plane is moved this far (mm) away from the objects, so that it never touches them.

    Returns:
        ``(point (3,), up (3,))``: a point of the plane under the pile's centre and its unit normal towards the
        objects and the cameras; None where no hull face has every camera behind it (cameras all around).
        Objects and cameras are on the same side, so the plane hides no object from any camera.
    """
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = ConvexHull(np.asarray(points, dtype=np.float64))
    except (QhullError, ValueError):  # flat or too few points
        return None
    normals, offsets = hull.equations[:, :3], hull.equations[:, 3]  # outward: n . x + d <= 0 inside
    tri = hull.points[hull.simplices]
    areas = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    behind = (np.asarray(eyes, dtype=np.float64) @ normals.T + offsets < 0).all(axis=0)  # every camera inside
    if not behind.any():
        return None
    idx = np.flatnonzero(behind)
    same = (normals[idx] @ normals[idx].T > 1 - 1e-6) & (np.abs(offsets[idx, None] - offsets[None, idx]) < 1e-2)
    best = idx[int(np.argmax(same @ areas[idx]))]  # the face (its coplanar triangles together) of largest area
    n, d = normals[best], offsets[best]
    centre = hull.points[hull.vertices].mean(axis=0)
    point = centre - (n @ centre + d) * n + margin * n
    return point, -n


def up_frame(up: np.ndarray) -> np.ndarray:
    """``(3, 3)`` rotation whose third column is ``up`` (unit): the plane's frame (columns: e1, e2, up)."""
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(helper, up)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(up, e1), up], axis=1)
