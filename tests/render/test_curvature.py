"""Curvature maps: equal to scipy's Prewitt per channel, seam-free on smoothed tessellations."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from scipy import ndimage

from bop_cender.render.curvature import curvature, curvature_valid
from bop_cender.render.mesh import prepare_mesh
from bop_cender.render.rasterizer import render_scene

try:
    from tests.render.reference import K_matrix, bracket, pose
except ImportError:  # pytest's default import mode puts tests/render itself on sys.path
    from reference import K_matrix, bracket, pose

H, W = 96, 128
K = K_matrix(300.0, 300.0, 63.7, 48.2)

# The `device` fixture (CPU, and CUDA where present) is in tests/conftest.py.


def scipy_curvature(normals: np.ndarray) -> np.ndarray:
    """The definition, with scipy: Prewitt of each 2-D channel along x and y (default 'reflect')."""
    grads = []
    for c in range(3):
        channel = normals[..., c].astype(np.float64)
        grads += [ndimage.prewitt(channel, axis=1), ndimage.prewitt(channel, axis=0)]
    return np.sqrt(sum(g * g for g in grads))


def rendered_normals(mesh: trimesh.Trimesh, T: np.ndarray, crease: float = 30.0) -> torch.Tensor:
    return render_scene([prepare_mesh(mesh, crease)], T[None, None], K[None], H, W).normals[0]


def test_equals_scipy_prewitt_per_channel(device) -> None:
    normals = rendered_normals(bracket(), pose((-30, 40, 25), (0, 0, 260)))
    normals[0, :] = normals[40]  # object pixels on the image border exercise the 'reflect' border rule
    ours = curvature(normals.to(device)).cpu().numpy()
    expected = scipy_curvature(normals.numpy())
    assert expected.max() > 1.0
    assert np.abs(ours - expected).max() <= 1e-5


def test_batched_and_valid_forms_agree() -> None:
    normals = torch.stack([rendered_normals(bracket(), pose((r, 40, 25), (0, 0, 260))) for r in (-30, 60, 150)])
    batch = curvature(normals.view(3, 1, H, W, 3))
    assert batch.shape == (3, 1, H, W)
    for i in range(3):
        assert torch.allclose(batch[i, 0], curvature(normals[i]), atol=1e-6)
    interior = curvature_valid(normals.permute(0, 3, 1, 2))
    assert torch.allclose(interior, batch[:, 0, 1:-1, 1:-1], atol=1e-6)
    with pytest.raises(ValueError):
        curvature(normals[..., :2])


def test_smoothed_cylinder_side_has_no_seams_and_box_edges_are_strong() -> None:
    cylinder = trimesh.creation.cylinder(radius=18, height=60, sections=24)  # 15 degrees between facets
    T = pose((90, 0, 0), (0, 0, 200))  # axis along the image's y: the curved side faces the camera
    side = np.zeros((H, W), dtype=bool)
    side[30:66, 50:78] = True  # well inside the side's silhouette (about 36 x 54 px), away from the rims
    smooth = curvature(rendered_normals(cylinder, T, 30.0)).numpy()
    flat = curvature(rendered_normals(cylinder, T, 0.0)).numpy()
    assert rendered_normals(cylinder, T).norm(dim=-1).numpy()[side].min() > 0.99  # all side pixels
    # Flat shading: 15-degree steps between facets give seams; smoothing leaves a gentle, even field.
    assert flat[side].max() > 0.6
    assert smooth[side].max() < 0.35
    # A box edge (90 degrees, far beyond the 30-degree crease angle) stays sharp.
    box = curvature(rendered_normals(trimesh.creation.box((40, 40, 40)), pose((0, 35, 0), (0, 0, 200)), 30.0))
    assert box.max() > 2.0
    assert (box > 1.0).sum() > 3 * 40  # the silhouette and the vertical edge between the two faces
