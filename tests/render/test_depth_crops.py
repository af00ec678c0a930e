"""Tight-window depth crops against the square windows of ``render_candidates`` and the full frame: bit-identical."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from bop_cender.eval.depth_render import render_depth_crops
from bop_cender.render.depth_crops import tight_depth_crops
from bop_cender.render.mesh import prepare_mesh
from bop_cender.render.rasterizer import render_candidates, render_objects_separately
from bop_cender.render.window import window_size

try:
    from tests.render.reference import K_matrix, bracket
except ImportError:  # pytest's default import mode puts tests/render itself on sys.path
    from reference import K_matrix, bracket

H, W = 120, 160


def random_poses(rng: np.random.Generator, n: int, radius: float, K: np.ndarray) -> np.ndarray:
    """``(n, 4, 4)`` poses: most in view, some partly or wholly outside the image, some near the near plane."""
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.random(n, random_state=rng.integers(1 << 31)).as_matrix()
    z = rng.uniform(2.0 * radius, 12.0 * radius, n)
    z[: n // 8] = radius + rng.uniform(0.2, 3.0, n // 8)  # sphere reaches (or nearly reaches) the near plane
    u = rng.uniform(-0.4 * W, 1.4 * W, n)  # origin projected up to 40 % beyond the borders
    v = rng.uniform(-0.4 * H, 1.4 * H, n)
    T[:, 0, 3] = (u - K[0, 2]) * z / K[0, 0]
    T[:, 1, 3] = (v - K[1, 2]) * z / K[1, 1]
    T[:, 2, 3] = z
    return T


def full_frame(mesh, T: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Reference depth ``(E, H, W)`` of each pose rendered alone in the whole image."""
    r = render_objects_separately([mesh], T[:, None], np.stack([K] * len(T)), H, W)
    return r.depth[:, 0].numpy()


def paste(crop: np.ndarray, origin: np.ndarray) -> np.ndarray:
    out = np.zeros((H, W), np.float32)
    out[origin[0] : origin[0] + crop.shape[0], origin[1] : origin[1] + crop.shape[1]] = crop
    return out


@pytest.mark.parametrize("seed", [0, 1])
def test_tight_crops_equal_square_windows_and_full_frame(seed: int) -> None:
    mesh = prepare_mesh(bracket())
    K = K_matrix(210.0, 205.0, 80.3, 59.6)
    T = random_poses(np.random.default_rng(seed), 96, mesh.radius, K)
    crops, origin = tight_depth_crops(mesh, T, np.stack([K] * len(T)), H, W, chunk_pixels=1 << 12)
    full = full_frame(mesh, T, K)
    # Square windows hold the whole silhouette unless capped at the image's larger side (objects very close).
    cap = int(np.ceil(max(H, W) / 8) * 8)
    Tt, Kt = torch.as_tensor(T, dtype=torch.float32), torch.as_tensor(K, dtype=torch.float32)[None]
    sizes = np.array([window_size(mesh.radius, Tt[e, None, None], Kt, H, W) for e in range(len(T))])
    in_front = np.flatnonzero((T[:, 2, 3] - mesh.radius > 1.0) & (sizes < cap))
    r = render_candidates(mesh, T[in_front, None], K[None], H, W, depth=True, normals=False)
    square, offsets = r.depth[:, 0].numpy(), r.offsets[:, 0].numpy()
    assert len(T) // 2 < len(in_front) < len(T)
    for e in range(len(T)):
        pasted = paste(crops[e], origin[e])
        np.testing.assert_array_equal(pasted, full[e])
        if crops[e].size:
            rows, cols = np.flatnonzero(crops[e].any(1)), np.flatnonzero(crops[e].any(0))
            assert rows[0] == 0 and rows[-1] == crops[e].shape[0] - 1 and cols[0] == 0 and cols[-1] == cols.size - 1
        else:
            assert not full[e].any()
    S = square.shape[1]
    for k, e in enumerate(in_front.tolist()):
        v0, u0 = offsets[k] + 2 * S
        ref = np.zeros((H + 4 * S, W + 4 * S), np.float32)
        ref[v0 : v0 + S, u0 : u0 + S] = square[k]
        np.testing.assert_array_equal(paste(crops[e], origin[e]), ref[2 * S : 2 * S + H, 2 * S : 2 * S + W])
    touching = [e for e in range(len(T)) if crops[e].size and (origin[e] == 0).any()]
    assert touching and any(not c.size for c in crops)  # poses cut by the border, poses wholly outside


def test_render_depth_crops_matches_full_frame_and_handles_edge_cases() -> None:
    mesh = prepare_mesh(bracket())
    K = K_matrix(210.0, 205.0, 80.3, 59.6)
    T = random_poses(np.random.default_rng(7), 40, mesh.radius, K)
    T[-1, 2, 3] = 0.5  # origin before the near plane
    crops = render_depth_crops(mesh, T, np.stack([K] * len(T)), H, W)
    full = full_frame(mesh, T, K)
    for e in range(len(T)):
        np.testing.assert_array_equal(paste(crops.depth[e], crops.origin[e]), full[e])
    empty, origin = tight_depth_crops(mesh, np.zeros((0, 4, 4)), np.zeros((0, 3, 3)), H, W)
    assert empty == [] and origin.shape == (0, 2)
