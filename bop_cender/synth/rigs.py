"""Camera rigs for synthetic scenes: DIMO's fixed robot viewpoints and T-LESS's per-image cameras.

All cameras are OpenCV pinhole cameras (x right, y down, z forward), world z up, mm, and poses are
``T_cam_world`` (world-to-camera). DIMO images a pile from 13 viewpoints that are the same in every
scene (the robot repeats them), so :func:`dimo_rig` is a pure function of its arguments. T-LESS test
images come from a turntable sweep with a per-image crop, so :func:`tless_cameras` draws each camera
(azimuth, elevation, distance, look-at offset, principal point) from an explicit generator.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from bop_cender.geometry.poses import make_pose

#: DIMO "small" images (JAI GO-5000 2560x2048 scaled by 1/8).
DIMO_WIDTH, DIMO_HEIGHT = 320, 256
#: T-LESS Primesense test images and a typical focal length (``cam_K`` of a test image, px).
TLESS_WIDTH, TLESS_HEIGHT = 720, 540
TLESS_FX, TLESS_FY = 1075.65, 1073.90
#: T-LESS test camera-object distances (bop_toolkit ``dataset_params``: 649.89-940.04 mm).
TLESS_DISTANCE_RANGE_MM = (650.0, 940.0)
#: T-LESS test views: elevations 15-75 deg above the turntable plane (7 rings of 72 azimuths = 504 images).
TLESS_ELEVATION_RANGE_DEG = (15.0, 75.0)


def look_at(
    eye: Sequence[float] | np.ndarray,
    target: Sequence[float] | np.ndarray,
    up: Sequence[float] | np.ndarray = (0.0, 0.0, 1.0),
) -> np.ndarray:
    """World-to-camera pose ``(4, 4)`` of an OpenCV camera at ``eye (3,)`` looking at ``target (3,)``.

    The optical axis (+z) points from ``eye`` to ``target``; ``up (3,)`` (world) appears upwards in the
    image, i.e. the camera's +y (image down) is minus the part of ``up`` orthogonal to the axis.

    Raises:
        ValueError: ``eye == target`` or ``up`` parallel to the viewing direction.
    """
    eye = np.asarray(eye, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - eye
    norm = np.linalg.norm(forward)
    if norm < 1e-9:
        raise ValueError("look_at: eye and target coincide")
    z = forward / norm
    up = np.asarray(up, dtype=np.float64)
    up_perp = up - (up @ z) * z
    if np.linalg.norm(up_perp) < 1e-9 * max(np.linalg.norm(up), 1.0):
        raise ValueError(f"look_at: up {up.tolist()} is parallel to the viewing direction {z.tolist()}")
    y = -up_perp / np.linalg.norm(up_perp)
    x = np.cross(y, z)
    R_cam_world = np.stack([x, y, z])  # rows: camera axes in world coordinates
    return make_pose(R_cam_world, -R_cam_world @ eye)


def dimo_rig(
    n_viewpoints: int = 13,
    distance_mm: float = 600.0,
    width: int = DIMO_WIDTH,
    height: int = DIMO_HEIGHT,
    fx: float = 450.0,
    *,
    target: Sequence[float] = (0.0, 0.0, 0.0),
    elevations_deg: tuple[float, float] = (65.0, 40.0),
) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """DIMO's fixed viewpoints: ``[(viewpoint_id, K (3, 3), T_cam_world (4, 4))]``, ids ``0..n-1``.

    Layout for 13: id 0 straight above ``target``; ids 1-6 a ring at ``elevations_deg[0]`` (azimuth
    ``60 * (k - 1)`` deg); ids 7-12 a ring at ``elevations_deg[1]`` turned by 30 deg (azimuth
    ``30 + 60 * (k - 7)``). The paper's even ids (0, 2, ..., 12) thus look from 0 (top), 60, 180, 300,
    90, 210 and 330 deg: all around the pile. Other counts fill the rings the same way (one top view,
    the rest split between the two rings). Every camera keeps world +z up in its image; the top view
    has the image up along world -x, as the azimuth-0 camera of the ring does, so neighbours do not
    roll against each other.

    With the defaults (600 mm, fx 450 px on 320x256) the image spans about 430 x 340 mm at the
    target: a carrier of 250-320 mm with a pile of 20-150 mm parts fills most of it. ``target`` must be
    the same for every scene of a dataset (the viewpoints are fixed); put the carrier top there.
    """
    if n_viewpoints < 1:
        raise ValueError(f"need at least one viewpoint, got {n_viewpoints}")
    target = np.asarray(target, dtype=np.float64)
    K = intrinsics(fx, fx, width / 2.0, height / 2.0)
    n_ring = n_viewpoints - 1
    n_first = (n_ring + 1) // 2
    rig = [(0, K.copy(), look_at(target + [0.0, 0.0, distance_mm], target, up=(-1.0, 0.0, 0.0)))]
    for k in range(1, n_viewpoints):
        ring = 0 if k <= n_first else 1
        i = k - 1 if ring == 0 else k - 1 - n_first
        n = n_first if ring == 0 else n_ring - n_first
        azimuth = 2.0 * np.pi * (i + 0.5 * ring) / n
        eye = target + distance_mm * _direction(azimuth, np.deg2rad(elevations_deg[ring]))
        rig.append((k, K.copy(), look_at(eye, target)))
    return rig


def tless_cameras(
    n_images: int,
    rng: np.random.Generator,
    width: int = TLESS_WIDTH,
    height: int = TLESS_HEIGHT,
    distance_range: tuple[float, float] = TLESS_DISTANCE_RANGE_MM,
    elevation_range_deg: tuple[float, float] = TLESS_ELEVATION_RANGE_DEG,
    jitter_px: float = 8.0,
    *,
    target: Sequence[float] = (0.0, 0.0, 0.0),
    look_at_offset_mm: float = 30.0,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per-image T-LESS-like cameras ``[(K (3, 3), T_cam_world (4, 4))]`` around ``target``.

    Each camera sits at a uniform azimuth, an elevation uniform in ``elevation_range_deg`` and a
    distance from ``target`` uniform in ``distance_range`` (mm), looks at ``target`` plus a uniform
    offset of up to ``look_at_offset_mm`` per axis, and keeps world +z up in its image. Its ``K`` has
    T-LESS's focal lengths and a principal point shifted from the image centre by up to ``jitter_px``
    per axis, as the per-image crops of T-LESS do (so no two images share one ``K``).
    """
    target = np.asarray(target, dtype=np.float64)
    azimuth = rng.uniform(0.0, 2.0 * np.pi, size=n_images)
    elevation = np.deg2rad(rng.uniform(*elevation_range_deg, size=n_images))
    distance = rng.uniform(*distance_range, size=n_images)
    offset = rng.uniform(-look_at_offset_mm, look_at_offset_mm, size=(n_images, 3))
    principal = np.array([width / 2.0, height / 2.0]) + rng.uniform(-jitter_px, jitter_px, size=(n_images, 2))
    cameras = []
    for i in range(n_images):
        eye = target + distance[i] * _direction(azimuth[i], elevation[i])
        scale = width / TLESS_WIDTH  # smaller test images keep T-LESS's field of view
        K = intrinsics(TLESS_FX * scale, TLESS_FY * scale, principal[i, 0], principal[i, 1])
        cameras.append((K, look_at(eye, target + offset[i])))
    return cameras


def intrinsics(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """Pinhole ``K (3, 3)``; ``(cx, cy)`` in the continuous image coordinates of the pixel convention."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def _direction(azimuth: float, elevation: float) -> np.ndarray:
    """Unit vector ``(3,)`` at ``azimuth`` (from +x towards +y) and ``elevation`` above the xy plane (rad)."""
    return np.array([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
