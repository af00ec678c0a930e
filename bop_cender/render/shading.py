"""Synthetic RGB shaded in torch from the batched renderer's own outputs.

Why here and not OpenGL: the images must be pixel-exact with the ground truth (masks, depth,
curvature targets), so they are shaded from the very depth / normal / instance buffers that the
ground truth comes from. One renderer, no GL context, CPU and CUDA alike.

The model, per pixel of one view (all tensors on the inputs' device, float32):
- position from depth through the pixel centre (u + 0.5, v + 0.5);
- metallic microfacet BRDF: GGX distribution, Schlick Fresnel with F0 = mix(0.04, base, metallic),
  Smith-Schlick visibility, for each point light, times the light's shadow-map visibility;
- image-based reflections: the mirror direction looked up in an equirectangular environment map
  pre-blurred at several roughness levels (split-sum style, no importance sampling), plus a
  diffuse ambient term from the most blurred level;
- brushed / saw-pattern anisotropy as a procedural stripe modulation of roughness in model-free
  world coordinates (cheap and view-consistent);
- background pixels get a background image; the carrier gets a world-xy texture.
The sensor model (gain, noise, blur, vignetting) is separate: :func:`apply_sensor`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F


@dataclass(frozen=True)
class Material:
    """Surface parameters of one object instance.

    Attributes:
        base_color: ``(3,)`` linear RGB in [0, 1] (metal F0 colour, or diffuse albedo).
        metallic: 0 dielectric .. 1 metal.
        roughness: GGX roughness in [0.02, 1].
        stripes: amplitude of the brushed / saw-pattern roughness modulation (0 = none).
        stripe_period_mm: period of that pattern.
        texture: use the world-xy texture for the albedo (carriers: cardboard, wood).
    """

    base_color: tuple[float, float, float]
    metallic: float
    roughness: float
    stripes: float = 0.0
    stripe_period_mm: float = 2.0
    texture: bool = False


@dataclass(frozen=True)
class PointLight:
    """A point light in world coordinates (mm) with linear RGB colour times intensity."""

    position: tuple[float, float, float]
    color: tuple[float, float, float]
    intensity: float


@dataclass
class EnvironmentMap:
    """Equirectangular environment (world z up) pre-blurred at increasing roughness.

    Attributes:
        levels: ``(L, 3, h, w)`` radiance, level 0 sharp (roughness 0), level L-1 ~ diffuse.
    """

    levels: torch.Tensor

    def lookup(self, dirs_world: torch.Tensor, roughness: torch.Tensor) -> torch.Tensor:
        """Radiance ``(N, 3)`` in unit directions ``(N, 3)`` at roughness ``(N,)`` (trilinear)."""
        L = self.levels.shape[0]
        x, y, z = dirs_world.unbind(-1)
        u = torch.atan2(y, x) / math.pi  # [-1, 1] over azimuth
        v = -torch.asin(z.clamp(-1, 1)) / (math.pi / 2)  # [-1, 1], top of the image = up
        grid = torch.stack([u, v], -1).view(1, 1, -1, 2).expand(L, 1, -1, 2)
        samples = F.grid_sample(self.levels, grid, mode="bilinear", padding_mode="border", align_corners=False)
        samples = samples.view(L, 3, -1).permute(2, 0, 1)  # (N, L, 3)
        level = roughness.clamp(0, 1).sqrt() * (L - 1)
        lo = level.floor().long().clamp(max=L - 1)
        hi = (lo + 1).clamp(max=L - 1)
        w = (level - lo.float()).unsqueeze(-1)
        idx = torch.arange(samples.shape[0], device=samples.device)
        return samples[idx, lo] * (1 - w) + samples[idx, hi] * w


def make_environment(
    rng: np.random.Generator, style: str = "studio", size: tuple[int, int] = (64, 128), levels: int = 5, device=None
) -> EnvironmentMap:
    """A procedural environment: sky/floor gradient plus bright soft-boxes ("studio") or windows ("hall").

    The bright patches are what metal parts reflect; their random placement makes reflections
    differ between scenes. ``hall`` (the real-camera model) has harder, more numerous patches.
    """
    h, w = size
    v, u = np.meshgrid(np.linspace(0.5 / h, 1 - 0.5 / h, h), np.linspace(0.5 / w, 1 - 0.5 / w, w), indexing="ij")
    elev = (0.5 - v) * np.pi
    azim = (u * 2 - 1) * np.pi
    sky = rng.uniform(0.15, 0.5, 3) * (0.6 + 0.4 * np.sin(np.clip(elev, 0, None)))[..., None]
    floor = rng.uniform(0.03, 0.15, 3) * np.ones_like(elev)[..., None]
    env = np.where((elev > 0)[..., None], sky, floor)
    n_patches = int(rng.integers(2, 5)) if style == "studio" else int(rng.integers(5, 10))
    sharpness = 6.0 if style == "studio" else 30.0
    dirs = np.stack([np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)], -1)
    for _ in range(n_patches):
        a, e = rng.uniform(-np.pi, np.pi), rng.uniform(0.1, 1.3)
        c = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
        size_rad = rng.uniform(0.15, 0.45) if style == "studio" else rng.uniform(0.05, 0.2)
        ang = np.arccos(np.clip(dirs @ c, -1, 1))
        patch = 1.0 / (1.0 + np.exp(np.clip((ang - size_rad) * sharpness / size_rad, -50, 50)))
        env = env + patch[..., None] * rng.uniform(1.0, 4.0) * rng.uniform(0.8, 1.0, 3)
    base = torch.as_tensor(env, dtype=torch.float32, device=device).permute(2, 0, 1)
    out = [base]
    for k in range(1, levels):
        sigma = 1.5 * 2**k
        out.append(_blur_wrap(base, sigma))
    return EnvironmentMap(torch.stack(out))


def _blur_wrap(img: torch.Tensor, sigma: float) -> torch.Tensor:
    """Separable Gaussian blur of ``(3, h, w)``, wrapping in azimuth, clamping in elevation."""
    r = max(1, int(3 * sigma))
    x = torch.arange(-r, r + 1, dtype=img.dtype, device=img.device)
    k = torch.exp(-0.5 * (x / sigma) ** 2)
    k = k / k.sum()
    h, w = img.shape[1:]
    padded = torch.cat([img[..., -min(r, w) :], img, img[..., : min(r, w)]], dim=-1)
    while padded.shape[-1] < w + 2 * r:  # blur wider than the map: wrap repeatedly
        padded = torch.cat([padded[..., -r:], padded, padded[..., :r]], dim=-1)
    off = (padded.shape[-1] - (w + 2 * r)) // 2
    padded = padded[..., off : off + w + 2 * r]
    out = F.conv2d(padded.unsqueeze(1), k.view(1, 1, 1, -1)).squeeze(1)
    out = F.pad(out.unsqueeze(1), (0, 0, r, r), mode="replicate")
    return F.conv2d(out, k.view(1, 1, -1, 1)).squeeze(1)


def world_points(depth: torch.Tensor, K: torch.Tensor, T_cam_world: torch.Tensor) -> torch.Tensor:
    """World coordinates ``(H, W, 3)`` of each pixel's surface point (depth z in mm, 0 = none)."""
    H, W = depth.shape
    dev, dt = depth.device, depth.dtype
    v, u = torch.meshgrid(torch.arange(H, device=dev, dtype=dt), torch.arange(W, device=dev, dtype=dt), indexing="ij")
    x = (u + 0.5 - K[0, 2]) / K[0, 0]
    y = (v + 0.5 - K[1, 2]) / K[1, 1]
    p_cam = torch.stack([x * depth, y * depth, depth], -1)
    R, t = T_cam_world[:3, :3], T_cam_world[:3, 3]
    return (p_cam - t) @ R  # R^T (p - t)


def shade_view(
    depth: torch.Tensor,
    normals: torch.Tensor,
    instance: torch.Tensor,
    K: torch.Tensor,
    T_cam_world: torch.Tensor,
    materials: list[Material],
    lights: list[PointLight],
    env: EnvironmentMap,
    shadow: torch.Tensor | None,
    background: torch.Tensor,
    texture: torch.Tensor | None = None,
    texture_mm_per_px: float = 1.0,
    exposure: float = 1.0,
) -> torch.Tensor:
    """Linear RGB ``(H, W, 3)`` of one view.

    Args:
        depth: ``(H, W)`` z in mm, 0 = background.
        normals: ``(H, W, 3)`` unit view-space normals.
        instance: ``(H, W)`` index into ``materials``, -1 = background.
        K: ``(3, 3)``; T_cam_world: ``(4, 4)``.
        materials: one per instance index.
        lights: point lights (world, mm).
        env: environment map for reflections and ambient light.
        shadow: ``(L, H, W)`` 1 = lit by light l, 0 = in its shadow (None: no shadows).
        background: ``(H, W, 3)`` linear RGB for background pixels.
        texture: ``(h, w, 3)`` albedo texture tiled over world xy (carriers with ``texture=True``).
        exposure: global scale before the sensor.
    """
    dev = depth.device
    H, W = depth.shape
    fg = instance >= 0
    out = background.clone()
    if not bool(fg.any()):
        return out * exposure
    inst = instance[fg]
    mats = _material_table(materials, dev)
    base, metallic, rough, stripes, period, textured = (m[inst] for m in mats)
    P = world_points(depth, K, T_cam_world)[fg]  # (N, 3)
    R = T_cam_world[:3, :3]
    n = F.normalize(normals[fg] @ R, dim=-1)  # view -> world
    cam_centre = -R.T @ T_cam_world[:3, 3]
    v = F.normalize(cam_centre - P, dim=-1)
    n = torch.where(((n * v).sum(-1, keepdim=True) < 0), -n, n)  # shade back-facing pixels as front
    if texture is not None:
        th, tw = texture.shape[:2]
        ij = (P[:, :2] / texture_mm_per_px).floor().long()
        tex = texture[ij[:, 1] % th, ij[:, 0] % tw]
        base = torch.where(textured.unsqueeze(-1) > 0, base * tex, base)
    # Brushed / saw patterns: roughness stripes along world x (view-consistent).
    rough = (rough * (1 + stripes * torch.sin(2 * math.pi * P[:, 0] / period))).clamp(0.02, 1.0)
    f0 = 0.04 * (1 - metallic).unsqueeze(-1) + base * metallic.unsqueeze(-1)
    diffuse_albedo = base * (1 - metallic).unsqueeze(-1)
    n_dot_v = (n * v).sum(-1).clamp(min=1e-4)
    alpha = rough * rough
    color = torch.zeros_like(P)
    for li, light in enumerate(lights):
        to_l = torch.as_tensor(light.position, dtype=P.dtype, device=dev) - P
        dist2 = (to_l * to_l).sum(-1).clamp(min=1.0)
        l_dir = to_l / dist2.sqrt().unsqueeze(-1)
        h_dir = F.normalize(l_dir + v, dim=-1)
        n_dot_l = (n * l_dir).sum(-1).clamp(min=0)
        n_dot_h = (n * h_dir).sum(-1).clamp(min=0)
        v_dot_h = (v * h_dir).sum(-1).clamp(min=0)
        d = alpha**2 / (math.pi * ((n_dot_h**2) * (alpha**2 - 1) + 1) ** 2).clamp(min=1e-8)
        k = (rough + 1) ** 2 / 8
        g = (n_dot_v / (n_dot_v * (1 - k) + k)) * (n_dot_l / (n_dot_l * (1 - k) + k))
        fres = f0 + (1 - f0) * (1 - v_dot_h).pow(5).unsqueeze(-1)
        spec = fres * (d * g / (4 * n_dot_v * n_dot_l.clamp(min=1e-4))).unsqueeze(-1)
        radiance = torch.as_tensor(light.color, dtype=P.dtype, device=dev) * light.intensity / dist2.unsqueeze(-1)
        lit = shadow[li][fg].unsqueeze(-1) if shadow is not None else 1.0
        color = color + (diffuse_albedo / math.pi + spec) * radiance * n_dot_l.unsqueeze(-1) * lit
    refl = F.normalize(2 * (n * v).sum(-1, keepdim=True) * n - v, dim=-1)
    f_env = f0 + (1 - f0) * (1 - n_dot_v).pow(5).unsqueeze(-1) * (1 - rough).unsqueeze(-1)
    color = color + f_env * env.lookup(refl, rough)
    color = color + diffuse_albedo * env.lookup(n, torch.ones_like(rough))
    out[fg] = color
    return out * exposure


def _material_table(materials: list[Material], dev) -> tuple[torch.Tensor, ...]:
    base = torch.tensor([m.base_color for m in materials], dtype=torch.float32, device=dev)
    scalars = torch.tensor(
        [[m.metallic, m.roughness, m.stripes, m.stripe_period_mm, float(m.texture)] for m in materials],
        dtype=torch.float32,
        device=dev,
    )
    return (base, *scalars.unbind(-1))


@dataclass(frozen=True)
class SensorModel:
    """Camera response: gain, read/shot noise, blur, vignetting, colour cast, exponential tone curve, gamma."""

    gain: float = 1.0
    gamma: float = 2.2
    read_noise: float = 0.01
    shot_noise: float = 0.02
    blur_sigma_px: float = 0.0
    vignetting: float = 0.0
    color_cast: tuple[float, float, float] = (1.0, 1.0, 1.0)


def apply_sensor(linear_rgb: torch.Tensor, sensor: SensorModel, generator: torch.Generator) -> torch.Tensor:
    """uint8 ``(H, W, 3)`` from linear RGB: blur, vignetting, noise, tone curve, quantisation."""
    img = linear_rgb * sensor.gain * torch.tensor(sensor.color_cast, dtype=linear_rgb.dtype, device=linear_rgb.device)
    H, W, _ = img.shape
    if sensor.blur_sigma_px > 0:
        r = max(1, int(math.ceil(2 * sensor.blur_sigma_px)))
        x = torch.arange(-r, r + 1, dtype=img.dtype, device=img.device)
        k = torch.exp(-0.5 * (x / sensor.blur_sigma_px) ** 2)
        k = (k / k.sum()).view(1, 1, 1, -1)
        chw = F.pad(img.permute(2, 0, 1).unsqueeze(1), (r, r, r, r), mode="replicate")
        chw = F.conv2d(F.conv2d(chw, k), k.transpose(-1, -2))
        img = chw.squeeze(1).permute(1, 2, 0)
    if sensor.vignetting > 0:
        yy = torch.linspace(-1, 1, H, device=img.device).view(H, 1)
        xx = torch.linspace(-1, 1, W, device=img.device).view(1, W)
        img = img * (1 - sensor.vignetting * (xx**2 + yy**2) / 2).unsqueeze(-1)
    img = img.clamp(min=0)
    noise = torch.randn(img.shape, generator=generator, device=img.device, dtype=img.dtype)
    img = img + noise * torch.sqrt(sensor.read_noise**2 + sensor.shot_noise**2 * img)
    # Exponential tone curve: highlights on metal compress instead of clipping flat white.
    img = (1 - torch.exp(-img.clamp(min=0) * 1.6)).clamp(0, 1) ** (1 / sensor.gamma)
    return (img * 255 + 0.5).clamp(0, 255).to(torch.uint8)


def procedural_texture(rng: np.random.Generator, size: int = 256, kind: str = "cardboard") -> np.ndarray:
    """A tileable albedo texture ``(size, size, 3)`` float32 in [0, 1]: cardboard, wood or noise.

    Sums of a few random sinusoids (tileable by construction: integer frequencies) plus
    fine noise; enough structure to make the background non-trivial for the network.
    """
    yy, xx = np.meshgrid(np.arange(size) / size, np.arange(size) / size, indexing="ij")
    field = np.zeros((size, size))
    for _ in range(6):
        fx, fy = rng.integers(1, 12, 2)
        field += rng.uniform(0.2, 1.0) * np.sin(2 * np.pi * (fx * xx + fy * yy) + rng.uniform(0, 2 * np.pi))
    if kind == "wood":
        field = np.sin(field * 3.0 + 20 * yy * rng.uniform(0.5, 2))
    field = (field - field.min()) / (np.ptp(field) + 1e-9)
    base = {"cardboard": (0.55, 0.42, 0.28), "wood": (0.6, 0.45, 0.3)}.get(kind, tuple(rng.uniform(0.2, 0.8, 3)))
    tex = np.asarray(base)[None, None] * (0.75 + 0.35 * field[..., None])
    tex = tex * (1 + 0.08 * rng.standard_normal((size, size, 1)))
    return np.clip(tex, 0, 1).astype(np.float32)


def random_background(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """A random linear-RGB background ``(H, W, 3)``: a gradient plus a tiled procedural texture."""
    tex = procedural_texture(rng, 128, kind=str(rng.choice(["cardboard", "wood", "noise"])))
    reps = (height // 128 + 1, width // 128 + 1, 1)
    tiled = np.tile(tex, reps)[:height, :width]
    grad = np.linspace(rng.uniform(0.3, 1.0), rng.uniform(0.3, 1.0), height)[:, None, None]
    return (tiled * grad * rng.uniform(0.2, 0.6)).astype(np.float32)
