"""An independent reference for renderer tests: trimesh/embree ray casting, plus small test meshes.

Importable by other tests: ``from tests.render.reference import ...``. The rays are built here from
fx, fy, cx, cy and the pixel centre ``(u + 0.5, v + 0.5)`` (``shift`` moves that on purpose), not with
bop_cender's camera code, so that a shared mistake cannot hide.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from bop_cender.synth.reference_meshes import reference_bracket

try:
    from trimesh.ray.ray_pyembree import RayMeshIntersector
except ImportError:  # embreex missing: trimesh's pure-Python intersector (slower, same answers)
    from trimesh.ray.ray_triangle import RayMeshIntersector


@dataclass
class Hits:
    """Ray-cast maps ``(H, W)``: mask, depth (z, mm; 0 off the mesh), hit triangle (-1 off), point (H, W, 3)."""

    mask: np.ndarray
    depth: np.ndarray
    tri: np.ndarray
    point: np.ndarray


def K_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def raycast(mesh_cam: trimesh.Trimesh, K: np.ndarray, height: int, width: int, shift: float = 0.5) -> Hits:
    """First hits of the rays from the camera centre through ``(u + shift, v + shift)`` of every pixel.

    Args:
        mesh_cam: the mesh already in the camera frame (x right, y down, z forward), mm.
        K: pinhole intrinsics (no skew).
    """
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    v, u = np.meshgrid(np.arange(height, dtype=np.float64), np.arange(width, dtype=np.float64), indexing="ij")
    directions = np.stack([(u + shift - cx) / fx, (v + shift - cy) / fy, np.ones_like(u)], -1).reshape(-1, 3)
    origins = np.zeros_like(directions)
    locations, ray, tri = RayMeshIntersector(mesh_cam).intersects_location(origins, directions, multiple_hits=False)
    mask = np.zeros(height * width, dtype=bool)
    depth = np.zeros(height * width)
    tri_map = np.full(height * width, -1, dtype=np.int64)
    point = np.zeros((height * width, 3))
    mask[ray], depth[ray], tri_map[ray], point[ray] = True, locations[:, 2], tri, locations
    return Hits(
        mask.reshape(height, width),
        depth.reshape(height, width),
        tri_map.reshape(height, width),
        point.reshape(height, width, 3),
    )


def transformed(mesh: trimesh.Trimesh, T: np.ndarray) -> trimesh.Trimesh:
    out = mesh.copy()
    out.apply_transform(T)
    return out


def pose(rotvec_deg: tuple[float, float, float], t: tuple[float, float, float]) -> np.ndarray:
    """``(4, 4)`` from a rotation vector in degrees and a translation in mm."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(np.radians(rotvec_deg)).as_matrix()
    T[:3, 3] = t
    return T


def boundary(mask: np.ndarray) -> np.ndarray:
    """Pixels of ``mask`` or its complement that touch the other (4-neighbourhood), ``(H, W)`` bool."""
    padded = np.pad(mask, 1, mode="edge")
    differs = np.zeros_like(mask)
    for dv, du in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        differs |= padded[1 + dv : 1 + dv + mask.shape[0], 1 + du : 1 + du + mask.shape[1]] != mask
    return differs


def centroid(mask: np.ndarray) -> np.ndarray:
    """Mask centroid (x, y) in pixel-centre coordinates."""
    v, u = np.nonzero(mask)
    return np.array([u.mean() + 0.5, v.mean() + 0.5])


def mask_agreement(mine: np.ndarray, ref: np.ndarray) -> tuple[float, bool, float]:
    """(fraction of differing pixels over the reference's object pixels, whether all differences lie on
    the reference's boundary, centroid distance in pixels)."""
    differ = mine != ref
    fraction = differ.sum() / max(1, ref.sum())
    on_boundary = bool(np.all(boundary(ref)[differ]))
    shift = float(np.linalg.norm(centroid(mine) - centroid(ref))) if mine.any() and ref.any() else np.inf
    return float(fraction), on_boundary, shift


def bracket(sections: int = 24) -> trimesh.Trimesh:
    """The reference L-bracket with fewer hole segments (fast tests)."""
    return reference_bracket(sections)


def holed_plate(thickness: float = 4.0, sections: int = 24) -> trimesh.Trimesh:
    """60 x 40 mm plate with three through holes of 12 mm (manifold3d), centred at the origin."""
    plate = trimesh.creation.box((60, 40, thickness))
    holes = []
    for x in (-18, 0, 18):
        hole = trimesh.creation.cylinder(radius=6, height=3 * thickness + 10, sections=sections)
        hole.apply_translation((x, 0, 0))
        holes.append(hole)
    return trimesh.boolean.difference([plate, *holes], engine="manifold")
