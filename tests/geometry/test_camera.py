import numpy as np

from bop_cender.geometry import pixel_centers, pixel_rays, project_points, rays_in_world
from bop_cender.geometry.poses import invert_pose, make_pose, transform_points
from bop_cender.geometry.rotations import random_rotations

K = np.array([[600.0, 0, 160.0], [0, 610.0, 128.0], [0, 0, 1]])


def test_project_principal_point():
    np.testing.assert_allclose(project_points(K, [[0.0, 0, 500]]), [[160.0, 128.0]])


def test_pixel_centre_convention():
    c = pixel_centers(2, 3)
    assert c.shape == (2, 3, 2)
    np.testing.assert_array_equal(c[0, 0], [0.5, 0.5])
    np.testing.assert_array_equal(c[1, 2], [2.5, 1.5])


def test_rays_project_back_to_their_pixel():
    uv = pixel_centers(4, 5).reshape(-1, 2)
    d = pixel_rays(K, uv)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0)
    np.testing.assert_allclose(project_points(K, d * 700.0), uv, atol=1e-9)


def test_rays_in_world_hit_the_world_point():
    rng = np.random.default_rng(1)
    T_cam_world = make_pose(random_rotations(1, rng)[0], [10.0, -20.0, 600.0])
    X_world = np.array([[5.0, 7.0, -3.0]])
    uv = project_points(K, transform_points(T_cam_world, X_world))
    o, d = rays_in_world(T_cam_world, pixel_rays(K, uv))
    # The world point lies on the ray o + s d.
    v = X_world[0] - o
    np.testing.assert_allclose(np.cross(v, d[0]), 0.0, atol=1e-9)
    np.testing.assert_allclose(o, invert_pose(T_cam_world)[:3, 3])
