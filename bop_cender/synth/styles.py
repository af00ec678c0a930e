"""Appearance styles of synthetic images: materials, lights, environment and sensor per domain.

Four domains, so that there is a gap to measure between them:
- ``sim``: DIMO's synthetic camera (studio environment, clean metal, mild sensor noise);
- ``real``: DIMO's "real" camera, deliberately different in light, material and noise
  (hall environment with hard reflections, scratched/brushed metal with stronger saw patterns,
  warmer colour cast, vignetting, blur, more noise): a sim-to-real gap to measure;
- ``tless``: T-LESS-like textureless, non-reflective light-grey plastic, Primesense-like noise;
- ``pbr``: T-LESS ``train_pbr``-like renders: random object colours and lights;
- ``randomised``: domain randomisation for training sets (``bop-cender synth --appearance randomised``):
  metal (DIMO) or plastic (T-LESS), lights, environment, carrier, background, exposure and sensor drawn
  from ranges wider than the test domains' together, so that a network trained on it does not learn one
  renderer's look (the shipped networks lost a fifth of their DIMO and a quarter of their T-LESS result on
  images of another renderer). On T-LESS the table is also hidden from half the scenes (shaded as
  background): BOP test images show whatever the objects rest on, or nothing of it.

"Real-world lighting" in DIMO means the same light set-up for a scene's real capture and its sim
twins (variants 00 and 16-30): :func:`fixed_lights` is a pure function of the light id.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from bop_cender.render.shading import Material, PointLight, SensorModel

DOMAINS = ("sim", "real", "tless", "pbr", "randomised")
#: ``bop-cender synth --appearance`` values: the layout's own look of its training folders (DIMO's sim camera,
#: T-LESS's ``train_pbr`` renders), or domain randomisation of them. Test folders keep their look either way.
APPEARANCES = ("default", "randomised")


def check_appearance(appearance: str) -> None:
    """Raise ValueError unless ``appearance`` is one of :data:`APPEARANCES` (every synth spec's check)."""
    if appearance not in APPEARANCES:
        raise ValueError(f"appearance must be one of {', '.join(APPEARANCES)}, got {appearance!r}")


#: Surfaces of the ``randomised`` domain's objects: DIMO's metal parts, T-LESS's plastic ones.
SURFACES = ("metal", "plastic")
#: Background kinds: a tiled procedural texture under a gradient, or one flat colour.
BACKGROUNDS = ("texture", "flat")


@dataclass(frozen=True)
class Style:
    """Everything that decides how a view looks, apart from geometry."""

    domain: str
    materials: list[Material]  # one per object instance index (carrier/table included)
    lights: list[PointLight]
    env_style: str
    sensor: SensorModel
    exposure: float
    carrier_texture: str
    background: str = "texture"
    #: Instance indices rendered into depth and masks but shaded as background (a hidden table).
    hidden: tuple[int, ...] = ()


def fixed_lights(light_id: int, centre: np.ndarray) -> list[PointLight]:
    """The "real-world" light set-up number ``light_id``: deterministic, shared by real and sim twins."""
    rng = np.random.default_rng(9000 + int(light_id))
    return _random_lights(rng, centre, n=2 + int(light_id) % 2)


def random_lights(rng: np.random.Generator, centre: np.ndarray) -> list[PointLight]:
    """A random light set-up (DIMO variants with random lighting, T-LESS, PBR)."""
    return _random_lights(rng, centre, n=int(rng.integers(1, 4)))


def _random_lights(rng: np.random.Generator, centre: np.ndarray, n: int) -> list[PointLight]:
    lights = []
    for _ in range(n):
        azim = rng.uniform(0, 2 * np.pi)
        elev = rng.uniform(np.deg2rad(30), np.deg2rad(80))
        dist = rng.uniform(500, 1200)
        pos = centre + dist * np.array([np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)])
        color = tuple(float(c) for c in rng.uniform(0.85, 1.0, 3))
        lights.append(PointLight(tuple(float(p) for p in pos), color, float(rng.uniform(2e5, 8e5) * dist**2 / 7e5)))
    return lights


def metal_material(rng: np.random.Generator, domain: str) -> Material:
    """Reflective metal with random roughness; ``real`` adds stronger brushing and a warmer tint."""
    grey = rng.uniform(0.55, 0.9)
    tint = rng.uniform(0.95, 1.05, 3) if domain == "sim" else rng.uniform(0.95, 1.12, 3) * [1.05, 1.0, 0.9]
    rough = rng.uniform(0.1, 0.45) if domain == "sim" else rng.uniform(0.05, 0.3)
    stripes = rng.uniform(0.0, 0.4) if domain == "sim" else rng.uniform(0.3, 0.8)
    return Material(
        tuple(float(c) for c in np.clip(grey * tint, 0, 1)), 1.0, float(rough), float(stripes), float(rng.uniform(1, 4))
    )


def plastic_material(rng: np.random.Generator, colourful: bool) -> Material:
    """Textureless plastic: light grey (T-LESS) or a random colour (PBR training renders)."""
    base = rng.uniform(0.1, 0.9, 3) if colourful else np.full(3, rng.uniform(0.6, 0.8)) * rng.uniform(0.97, 1.03, 3)
    return Material(tuple(float(c) for c in np.clip(base, 0, 1)), 0.0, float(rng.uniform(0.5, 0.9)))


def carrier_material(rng: np.random.Generator) -> Material:
    """Cardboard / wood carriers and tables: diffuse, textured by the world-xy texture."""
    return Material((1.0, 1.0, 1.0), 0.0, float(rng.uniform(0.7, 1.0)), texture=True)


#: Uniform ranges of the sensor model's parameters per domain, drawn in this order (``tless``: fixed values).
SENSOR_RANGES = {
    "real": {
        "gain": (0.8, 1.2),
        "read_noise": (0.015, 0.03),
        "shot_noise": (0.03, 0.06),
        "blur_sigma_px": (0.5, 0.9),
        "vignetting": (0.2, 0.4),
    },
    "sim": {"gain": (0.9, 1.1), "read_noise": (0.003, 0.01), "shot_noise": (0.005, 0.02), "blur_sigma_px": (0.0, 0.4)},
    "randomised": {
        "gain": (0.7, 1.3),
        "read_noise": (0.0, 0.035),
        "shot_noise": (0.0, 0.07),
        "blur_sigma_px": (0.0, 1.0),
        "vignetting": (0.0, 0.45),
    },
}


def _draw_sensor(rng: np.random.Generator, domain: str, **fixed) -> SensorModel:
    """A sensor with ``SENSOR_RANGES[domain]`` drawn in their order, and the ``fixed`` fields as given."""
    return SensorModel(**{k: float(rng.uniform(*r)) for k, r in SENSOR_RANGES[domain].items()}, **fixed)


def sensor_model(rng: np.random.Generator, domain: str) -> SensorModel:
    """Noise, blur and colour response per domain (``real`` is the harshest)."""
    if domain == "real":
        cast = tuple(float(c) for c in rng.uniform(0.9, 1.1, 3) * [1.06, 1.0, 0.9])
        return _draw_sensor(rng, "real", color_cast=cast)
    if domain == "tless":
        return SensorModel(read_noise=0.01, shot_noise=0.02, blur_sigma_px=0.4, vignetting=0.1)
    return _draw_sensor(rng, "sim")


def randomised_metal(rng: np.random.Generator) -> Material:
    """Metal of any finish: from dark to bright, tinted, mirror-like to matte, plain to strongly brushed."""
    grey = rng.uniform(0.3, 0.95)
    tint = rng.uniform(0.85, 1.15, 3)
    return Material(
        tuple(float(c) for c in np.clip(grey * tint, 0, 1)),
        float(rng.uniform(0.7, 1.0)),
        float(rng.uniform(0.03, 0.7)),
        float(rng.uniform(0.0, 0.9)),
        float(rng.uniform(0.5, 5.0)),
    )


def randomised_plastic(rng: np.random.Generator) -> Material:
    """Plastic of any colour or grey, glossy to matte, now and then slightly metallic (painted or coated parts)."""
    if rng.uniform() < 0.5:
        base = np.full(3, rng.uniform(0.15, 0.9)) * rng.uniform(0.95, 1.05, 3)
    else:
        base = rng.uniform(0.05, 0.9, 3)
    return Material(
        tuple(float(c) for c in np.clip(base, 0, 1)),
        float(rng.uniform(0.0, 0.3)) if rng.uniform() < 0.2 else 0.0,
        float(rng.uniform(0.15, 1.0)),
    )


def randomised_carrier(rng: np.random.Generator) -> tuple[Material, str]:
    """A textured carrier (cardboard, wood or coloured noise) or a plain one of a random colour."""
    kind = str(rng.choice(["cardboard", "wood", "noise", "plain"]))
    if kind == "plain":
        colour = tuple(float(c) for c in rng.uniform(0.05, 0.8, 3))
        return Material(colour, 0.0, float(rng.uniform(0.4, 1.0))), "cardboard"
    return Material((1.0, 1.0, 1.0), 0.0, float(rng.uniform(0.4, 1.0)), texture=True), kind


def randomised_sensor(rng: np.random.Generator) -> SensorModel:
    """Noise, blur, vignetting and colour cast from none to more than the ``real`` camera's."""
    sensor = _draw_sensor(rng, "randomised")
    return replace(sensor, color_cast=tuple(float(c) for c in rng.uniform(0.85, 1.15, 3)))


def randomised_style(
    rng: np.random.Generator,
    n_objects: int,
    centre: np.ndarray,
    light_id: int | None = None,
    carrier_index: int | None = None,
    surface: str = "metal",
) -> Style:
    """The ``randomised`` domain: every appearance factor drawn wide (see the module docstring).

    A fixed light set-up (``light_id``) stays fixed, as in the other domains; only its brightness varies,
    through the exposure. ``surface`` (:data:`SURFACES`) picks the objects' materials; ``plastic`` (T-LESS)
    also hides the carrier from half the scenes. ``metal`` draws exactly what it drew before ``surface``
    existed (the same seed makes the same training set).
    """
    if surface not in SURFACES:
        raise ValueError(f"unknown surface {surface!r}; expected one of {SURFACES}")
    draw_object = randomised_metal if surface == "metal" else randomised_plastic
    materials = [Material((0.5, 0.5, 0.5), 0.0, 0.5)] * n_objects
    carrier_texture = "cardboard"
    for i in range(n_objects):
        if i == carrier_index:
            materials[i], carrier_texture = randomised_carrier(rng)
        else:
            materials[i] = draw_object(rng)
    if light_id is not None:
        lights = fixed_lights(light_id, centre)
    else:
        lights = _random_lights(rng, centre, n=int(rng.integers(1, 5)))
    return Style(
        domain="randomised",
        materials=materials,
        lights=lights,
        env_style=str(rng.choice(["studio", "hall"])),
        sensor=randomised_sensor(rng),
        exposure=float(rng.uniform(0.5, 1.6)),
        carrier_texture=carrier_texture,
        background=str(rng.choice(BACKGROUNDS)),
        hidden=_hidden_carrier(rng, carrier_index) if surface == "plastic" else (),
    )


def _hidden_carrier(rng: np.random.Generator, carrier_index: int | None) -> tuple[int, ...]:
    """The carrier's index with probability 0.5 (drawn even without a carrier, so the draws stay aligned)."""
    hide = rng.uniform() < 0.5
    return (carrier_index,) if hide and carrier_index is not None else ()


def make_style(
    rng: np.random.Generator,
    domain: str,
    n_objects: int,
    centre: np.ndarray,
    light_id: int | None = None,
    carrier_index: int | None = None,
    surface: str = "metal",
) -> Style:
    """A complete style for a scene of ``n_objects`` instances (index ``carrier_index`` is the carrier).

    Args:
        domain: one of :data:`DOMAINS`.
        light_id: use the fixed "real-world" light set-up with this id; None draws random lights.
        surface: the ``randomised`` domain's object materials (:data:`SURFACES`); the other domains have theirs.
    """
    if domain not in DOMAINS:
        raise ValueError(f"unknown domain {domain!r}; expected one of {DOMAINS}")
    if domain == "randomised":
        return randomised_style(rng, n_objects, centre, light_id, carrier_index, surface)
    materials = []
    for i in range(n_objects):
        if i == carrier_index:
            materials.append(carrier_material(rng))
        elif domain in ("sim", "real"):
            materials.append(metal_material(rng, domain))
        else:
            materials.append(plastic_material(rng, colourful=domain == "pbr"))
    lights = fixed_lights(light_id, centre) if light_id is not None else random_lights(rng, centre)
    return Style(
        domain=domain,
        materials=materials,
        lights=lights,
        env_style="hall" if domain == "real" else "studio",
        sensor=sensor_model(rng, domain),
        exposure=float(rng.uniform(0.8, 1.2)),
        carrier_texture=str(rng.choice(["cardboard", "wood"])),
    )
