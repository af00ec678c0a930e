import numpy as np
import pytest
import torch

from bop_cender.render.shading import (
    Material,
    PointLight,
    SensorModel,
    apply_sensor,
    make_environment,
    procedural_texture,
    random_background,
    shade_view,
    world_points,
)

H, W = 48, 64
K = torch.tensor([[80.0, 0, 32], [0, 80.0, 24], [0, 0, 1]])


def sphere_buffers(radius=40.0, z0=300.0):
    """Analytic depth / normals / instance of a sphere centred on the optical axis (camera = world)."""
    v, u = torch.meshgrid(torch.arange(H) + 0.5, torch.arange(W) + 0.5, indexing="ij")
    d = torch.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], torch.ones_like(u)], -1)
    d = d / d.norm(dim=-1, keepdim=True)
    c = torch.tensor([0.0, 0.0, z0])
    b = (d * c).sum(-1)
    disc = b**2 - (c @ c - radius**2)
    hit = disc > 0
    s = b - disc.clamp(min=0).sqrt()
    p = d * s.unsqueeze(-1)
    n = torch.nn.functional.normalize(p - c, dim=-1)
    depth = torch.where(hit, p[..., 2], torch.zeros(()))
    normals = torch.where(hit.unsqueeze(-1), n, torch.zeros(()))
    instance = torch.where(hit, 0, -1)
    return depth, normals, instance


def test_world_points_inverts_projection():
    depth, _, inst = sphere_buffers()
    P = world_points(depth, K, torch.eye(4))
    fg = inst >= 0
    dist = (P[fg] - torch.tensor([0.0, 0, 300.0])).norm(dim=-1)
    assert torch.allclose(dist, torch.full_like(dist, 40.0), atol=1e-3)


@pytest.mark.parametrize("metallic", [0.0, 1.0])
def test_shading_is_finite_bounded_and_keeps_background(metallic):
    rng = np.random.default_rng(0)
    depth, normals, inst = sphere_buffers()
    env = make_environment(rng)
    bg = torch.as_tensor(random_background(rng, H, W))
    mat = Material((0.8, 0.8, 0.85), metallic, 0.3, stripes=0.3)
    light = PointLight((200.0, -200.0, 0.0), (1.0, 1.0, 1.0), 2e5)
    rgb = shade_view(depth, normals, inst, K, torch.eye(4), [mat], [light], env, None, bg)
    assert rgb.shape == (H, W, 3) and torch.isfinite(rgb).all() and (rgb >= 0).all()
    assert torch.equal(rgb[inst < 0], bg[inst < 0])
    # The light's contribution peaks on the side facing it (upper right: -y, +x), diffuse or specular.
    unlit = shade_view(depth, normals, inst, K, torch.eye(4), [mat], [], env, None, bg)
    added = (rgb - unlit).mean(-1)
    row, col = divmod(int(added.argmax()), W)
    assert row < H // 2 and col > W // 2
    assert added.min() >= -1e-6


def test_shadow_darkens():
    rng = np.random.default_rng(1)
    depth, normals, inst = sphere_buffers()
    env = make_environment(rng)
    bg = torch.zeros(H, W, 3)
    mat = Material((0.7, 0.7, 0.7), 0.0, 0.6)
    light = PointLight((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 1e5)
    lit = shade_view(depth, normals, inst, K, torch.eye(4), [mat], [light], env, torch.ones(1, H, W), bg)
    dark = shade_view(depth, normals, inst, K, torch.eye(4), [mat], [light], env, torch.zeros(1, H, W), bg)
    fg = inst >= 0
    assert (lit[fg].sum(-1) > dark[fg].sum(-1) + 1e-3).all()


def test_sensor_deterministic_and_uint8():
    img = torch.full((H, W, 3), 0.3)
    sensor = SensorModel(read_noise=0.02, shot_noise=0.03, blur_sigma_px=0.7, vignetting=0.2)
    a = apply_sensor(img, sensor, torch.Generator().manual_seed(3))
    b = apply_sensor(img, sensor, torch.Generator().manual_seed(3))
    c = apply_sensor(img, sensor, torch.Generator().manual_seed(4))
    assert a.dtype == torch.uint8 and a.shape == (H, W, 3)
    assert torch.equal(a, b) and not torch.equal(a, c)
    # Vignetting: corners darker than the centre on average.
    assert a[:5, :5].float().mean() < a[20:28, 28:36].float().mean()


def test_texture_tiles_and_is_deterministic():
    t1 = procedural_texture(np.random.default_rng(5), 64)
    t2 = procedural_texture(np.random.default_rng(5), 64)
    assert t1.shape == (64, 64, 3) and np.array_equal(t1, t2)
    assert t1.min() >= 0 and t1.max() <= 1 and t1.std() > 0.01


def test_environment_lookup_levels():
    env = make_environment(np.random.default_rng(2), size=(16, 32), levels=3)
    dirs = torch.nn.functional.normalize(torch.randn(100, 3, generator=torch.Generator().manual_seed(0)), dim=-1)
    sharp = env.lookup(dirs, torch.zeros(100))
    blurry = env.lookup(dirs, torch.ones(100))
    assert sharp.shape == (100, 3) and torch.isfinite(sharp).all()
    assert blurry.std(0).mean() < sharp.std(0).mean()  # blur flattens the radiance
