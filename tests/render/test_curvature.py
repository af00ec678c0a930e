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


def test_the_root_is_correctly_rounded_on_every_machine(device) -> None:
    """The curvature's square root is IEEE's (what the compiled loops take), not the vector maths library's: on an
    AMD EPYC torch's own float32 sqrt gave sqrt(3.9999998) = 2.0 and was one ulp off for 18 % of random values, so
    the compiled renderer's curvature left torch's and the edge threshold 3.0 flipped pixels there."""
    from bop_cender.render.curvature import correctly_rounded_sqrt_

    rng = np.random.default_rng(0)
    near_nine = np.float32(9.0) + np.arange(-500, 500, dtype=np.float32) * np.float32(2.0**-20)
    x = np.concatenate([rng.random(200_000, dtype=np.float32) * 20, near_nine, [np.float32(3.9999998)]])
    x = x.astype(np.float32)
    root = correctly_rounded_sqrt_(torch.from_numpy(x.copy()).to(device)).cpu().numpy()
    assert root.dtype == np.float32
    np.testing.assert_array_equal(root, np.sqrt(x))  # NumPy's float32 root is the IEEE one


def test_torch_and_the_compiled_loops_give_the_same_curvature_bits() -> None:
    """torch's curvature (the CUDA path, and the CPU reference) and the compiled loops' per-pixel curvature agree bit
    for bit on random normals (at the EPYC, with torch's own root, 18 % of the pixels did not)."""
    from bop_cender.render.compiled_raster import AVAILABLE, pixel_curvature

    if not AVAILABLE:
        pytest.skip("the compiled loops cannot repeat torch's addcmul rounding here")
    from bop_cender.render.compiled_raster import ADDCMUL_FUSED

    h, w = 40, 50
    normals = torch.from_numpy(np.random.default_rng(1).normal(size=(h, w, 3)).astype(np.float32))
    ours = curvature(normals).numpy()
    maps = normals.numpy()
    loops = np.array(
        [
            [
                pixel_curvature(
                    maps, max(i - 1, 0), i, min(i + 1, h - 1), max(j - 1, 0), j, min(j + 1, w - 1), ADDCMUL_FUSED
                )
                for j in range(w)
            ]
            for i in range(h)
        ],
        dtype=np.float32,
    )
    np.testing.assert_array_equal(ours, loops)
