import numpy as np
import pytest
import torch

from bop_cender.geometry.check import check_shape


def test_fixed_and_named_sizes():
    sizes = check_shape(torch.zeros(2, 3, 4, 4), "B V 4 4", "T")
    assert sizes == {"B": 2, "V": 3}
    check_shape(np.zeros((3, 3, 3)), "V 3 3", "K", sizes)
    with pytest.raises(ValueError, match="K: expected V = 3"):
        check_shape(np.zeros((2, 3, 3)), "V 3 3", "K", sizes)
    with pytest.raises(ValueError, match=r"T: expected shape \(B, V, 4, 4\), got \(2, 3, 3, 4\)"):
        check_shape(torch.zeros(2, 3, 3, 4), "B V 4 4", "T")
    with pytest.raises(ValueError, match="expected shape"):
        check_shape(torch.zeros(4, 4), "B 4 4", "T")
    check_shape(torch.zeros(5, 7), "* 7", "any")


def test_public_entries_name_the_argument():
    import trimesh

    from bop_cender.pose.backend import backend_named
    from bop_cender.render.mesh import prepare_mesh

    candidate_costs = backend_named("auto").candidate_costs
    mesh = prepare_mesh(trimesh.creation.box(extents=(10.0, 10.0, 10.0)))
    T = torch.eye(4).repeat(2, 3, 1, 1)
    T[..., 2, 3] = 100.0
    K = torch.tensor([[100.0, 0, 16], [0, 100.0, 12], [0, 0, 1]]).repeat(3, 1, 1)
    dist = torch.zeros(3, 24, 32)
    w = torch.ones(3)
    assert candidate_costs(mesh, T, K, 24, 32, dist, w).shape == (2,)
    with pytest.raises(ValueError, match="K: expected V = 3"):
        candidate_costs(mesh, T, K[:2], 24, 32, dist, w)
    with pytest.raises(ValueError, match="dist_maps"):
        candidate_costs(mesh, T, K, 24, 32, dist[:, :10], w)
    with pytest.raises(ValueError, match="view_weights"):
        candidate_costs(mesh, T, K, 24, 32, dist, torch.ones(4))
    with pytest.raises(ValueError, match="T_cam_model"):
        candidate_costs(mesh, T[0], K, 24, 32, dist, w)
