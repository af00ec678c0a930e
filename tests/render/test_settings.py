"""One frozen settings value for the renderer: the module defaults come from it, bad values are refused."""

import pytest
import torch

from bop_cender.render import backend, candidate_curvature, depth_crops, raster
from bop_cender.render.settings import DEFAULT_RENDER_SETTINGS, RenderSettings


def test_module_defaults_come_from_the_settings():
    s = DEFAULT_RENDER_SETTINGS
    assert s.near == raster.DEFAULT_NEAR
    assert s.scene_chunk_pixels == backend.DEFAULT_CHUNK_PIXELS
    assert s.candidate_chunk_pixels(torch.device("cpu")) == candidate_curvature.DEFAULT_CHUNK_PIXELS
    assert s.depth_crop_chunk_pixels == depth_crops.DEFAULT_CHUNK_PIXELS
    assert s.candidate_chunk_pixels(torch.device("cuda")) == s.candidate_chunk_pixels_cuda


@pytest.mark.parametrize("kw", [{"near": 0.0}, {"scene_chunk_pixels": 0}, {"candidate_chunk_pixels_cpu": -1}])
def test_bad_settings_are_refused(kw):
    with pytest.raises(ValueError):
        RenderSettings(**kw)


def test_cost_takes_settings():
    import trimesh

    from bop_cender.pose.backend import backend_named
    from bop_cender.render.mesh import prepare_mesh

    candidate_costs = backend_named("auto").candidate_costs
    mesh = prepare_mesh(trimesh.creation.box(extents=(10.0, 10.0, 10.0)))
    T = torch.eye(4).repeat(3, 2, 1, 1)
    T[..., 2, 3] = 100.0
    T[1, :, 0, 3] = 2.0
    K = torch.tensor([[100.0, 0, 16], [0, 100.0, 12], [0, 0, 1]]).repeat(2, 1, 1)
    dist = torch.rand(2, 24, 32, generator=torch.Generator().manual_seed(0))
    w = torch.ones(2)
    default = candidate_costs(mesh, T, K, 24, 32, dist, w)
    one_canvas_chunks = candidate_costs(
        mesh, T, K, 24, 32, dist, w, settings=RenderSettings(candidate_chunk_pixels_cpu=1)
    )
    assert torch.allclose(default, one_canvas_chunks, atol=1e-5)
    # everything behind the near plane: nothing drawn, the diagonal cost
    far_near = candidate_costs(mesh, T, K, 24, 32, dist, w, settings=RenderSettings(near=500.0))
    assert torch.allclose(far_near, torch.full((3,), 2 * (24**2 + 32**2) ** 0.5))
