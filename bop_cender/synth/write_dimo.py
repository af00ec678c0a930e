"""Write a synthetic dataset in exactly the DIMO layout (docs/datasets.md, "DIMO").

Per scene number ``s``: ``real_jaigo/{s:06d}`` (the "real" camera model: other light, material and
noise, so there is a sim-to-real gap to measure) and ``sim_jaigo/{s:06d}_{v:02d}`` variants:
``00`` the sim twin of the real scene (same poses, same light set-up), ``01``-``15`` random light
with the real poses, ``16``-``30`` real light with random poses, ``31``-``70`` random light and
random poses. 13 fixed viewpoints (image id = viewpoint id), 320x256. Only the files real DIMO
has: ``rgb/``, ``scene_camera.json`` (c2w, plus the consistent w2c), ``scene_gt.json``,
``scene_gt_world.json``, ``scene_info.json``; models in ``models/`` (+ ``models_eval/``).

Our synthetic convention for ``scene_info`` values (DIMO does not document them): ``carrier`` c is
the model ``100 + c``; ``parts`` (composition) 1, 2 and 4 are piles of ONE part type with few /
medium / many parts, 0 and 3 are mixed types; ``light`` is the fixed set-up id for real lighting
and ``100 + variant`` for random lighting.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bop_cender.data.bop_io import save_json, write_image
from bop_cender.data.dimo import CARRIER_MIN_ID
from bop_cender.data.layout import SCENE_CAMERA, SCENE_GT
from bop_cender.meshes import MeshCache
from bop_cender.synth.bop_files import Pile, camera_entry, gt_entry, make_pile, scene_folder
from bop_cender.synth.contact_sheet import write_contact_sheet
from bop_cender.synth.done import scene_done
from bop_cender.synth.imaging import render_views
from bop_cender.synth.models_info import write_model_folders
from bop_cender.synth.parts import Part, make_carrier, make_part_set
from bop_cender.synth.piles import PileGeometryCache
from bop_cender.synth.rigs import dimo_rig
from bop_cender.synth.styles import check_appearance, make_style

N_CARRIERS = 3
#: (min, max) number of parts per composition id; compositions in SAME_TYPE use one part type.
COMPOSITION_SIZES = {0: (4, 6), 1: (3, 4), 2: (5, 6), 3: (5, 7), 4: (7, 9)}
SAME_TYPE = (1, 2, 4)
N_LIGHT_SETUPS = 4
#: The DIMO layout's one object catalogue (the demo's seed: the demo's models are unchanged).
DIMO_CATALOGUE_SEED = 20221023
#: The rig looks at this world point in every scene (the carriers' top is near z = 20 mm).
RIG_TARGET = (0.0, 0.0, 20.0)
#: Focal length (px) of the rig at DIMO small's 320x256.
RIG_FX = 450.0


@dataclass(frozen=True)
class DimoSpec:
    """What to generate.

    Attributes:
        n_scenes: scene numbers 0..n-1 (each a real scene plus its sim variants).
        n_viewpoints: views per scene (13 in DIMO).
        variants: sim suffixes to write per scene.
        carriers: carrier ids cycled over scenes (the paper selects carrier 2).
        compositions: composition ids cycled over scenes (the paper selects 1, 2, 4).
        width, height: image size (DIMO small: 320x256).
        seed: scenes, poses, light and materials derive from it (not the models: see ``catalogue_seed``).
        write_real: also write ``real_jaigo``.
        catalogue_seed: draws the object catalogue (which part type has which id, its dimensions, the
            carriers). Fixed per layout, as a real dataset has one catalogue, so that sets of other seeds
            share their objects (a network trained on one is tested on another); the default is the
            demo's seed, so the demo's models are the catalogue.
        appearance: ``default`` (the sim folders look like DIMO's synthetic camera) or ``randomised`` (the sim
            folders' materials, lights, environment, carrier, background and sensor drawn wide: domain
            randomisation for training sets; see :mod:`bop_cender.synth.styles`). ``real_jaigo`` keeps the
            real camera's look either way.
    """

    n_scenes: int = 3
    n_viewpoints: int = 13
    variants: tuple[int, ...] = (0, 3, 17, 40)
    carriers: tuple[int, ...] = (2,)
    compositions: tuple[int, ...] = (1, 2, 4)
    width: int = 320
    height: int = 256
    seed: int = 0
    write_real: bool = True
    contact_sheets: bool = True
    catalogue_seed: int = DIMO_CATALOGUE_SEED
    appearance: str = "default"

    def __post_init__(self) -> None:
        check_appearance(self.appearance)
        bad = [v for v in self.variants if not 0 <= v <= 70]
        if bad:
            raise ValueError(f"sim variants (--variants) must be 0..70, got {bad}")
        if any(c not in COMPOSITION_SIZES for c in self.compositions):
            raise ValueError(
                f"compositions (--compositions) must be among {sorted(COMPOSITION_SIZES)}, got {list(self.compositions)}"
            )
        if any(not 0 <= c < N_CARRIERS for c in self.carriers):
            raise ValueError(f"carriers (--carriers) must be 0..{N_CARRIERS - 1}, got {list(self.carriers)}")
        if self.seed < 0 or self.catalogue_seed < 0:
            raise ValueError(f"seeds must be >= 0, got seed {self.seed}, catalogue_seed {self.catalogue_seed}")


def dimo_models(catalogue_seed: int = DIMO_CATALOGUE_SEED) -> dict[int, Part]:
    """The catalogue: one part per type (ids 1..6) and the carriers (ids 100..102), drawn by ``catalogue_seed``."""
    rng = np.random.default_rng([catalogue_seed, 7])
    models = {i + 1: p for i, p in enumerate(make_part_set(rng, 6))}
    for c in range(N_CARRIERS):
        models[CARRIER_MIN_ID + c] = make_carrier(rng)
    return models


def write_models(root: Path, spec: DimoSpec) -> dict[int, Part]:
    """Write ``models/`` and ``models_eval/`` once (the catalogue of ``spec.catalogue_seed``); return the parts."""
    models = dimo_models(spec.catalogue_seed)
    write_model_folders(root, models, "dimo")
    return models


def scene_jobs(spec: DimoSpec) -> list[int]:
    """The independent units of work: scene numbers."""
    return list(range(spec.n_scenes))


def scene_carrier_and_composition(spec: DimoSpec, s: int) -> tuple[int, int]:
    """The carrier id and composition id of scene number ``s``: ``spec.carriers`` and ``spec.compositions`` cycled."""
    return spec.carriers[s % len(spec.carriers)], spec.compositions[s % len(spec.compositions)]


def job_folders(root: Path, spec: DimoSpec, s: int) -> list[Path]:
    """The scene folders of scene number ``s``: ``real_jaigo/{s:06d}`` and ``sim_jaigo/{s:06d}_{v:02d}``."""
    real = [Path(root) / "real_jaigo" / f"{s:06d}"] if spec.write_real else []
    return real + [Path(root) / "sim_jaigo" / f"{s:06d}_{v:02d}" for v in spec.variants]


def write_scene(
    root: Path,
    spec: DimoSpec,
    s: int,
    models: dict[int, Part],
    meshes: MeshCache,
    piles: PileGeometryCache | None = None,
) -> int:
    """Write the real scene ``s`` and its sim variants; skip folders that are done. Returns folders written.

    Which folders are done is known first, and only the piles of the others are dropped (a pile costs
    about a second, more than rendering its views): a resumed run does no work for a finished folder.
    """
    rng = np.random.default_rng([spec.seed, s])
    carrier, composition = scene_carrier_and_composition(spec, s)
    light_id = int(rng.integers(0, N_LIGHT_SETUPS))
    part_ids = [i for i in models if i < CARRIER_MIN_ID]
    type_index = int(rng.integers(0, len(part_ids)))
    lo, hi = COMPOSITION_SIZES[composition]

    def new_pile(pile_rng: np.random.Generator) -> Pile:
        comp = [type_index] if composition in SAME_TYPE else "mixed"
        n = int(pile_rng.integers(lo, hi + 1))
        cid = CARRIER_MIN_ID + carrier
        return make_pile(models, part_ids, cid, models[cid], n, comp, pile_rng, support_in_gt=True, cache=piles)

    real_pile: list[Pile] = []  # dropped once, when a folder that shows it is written

    def the_real_pile() -> Pile:
        if not real_pile:
            real_pile.append(new_pile(np.random.default_rng([spec.seed, s, 1000])))
        return real_pile[0]

    info = {"carrier": carrier, "parts": composition}
    # (folder, pile of the folder, domain, light set-up, scene_info light); every pile derives from its own
    # seed, so dropping only some of them gives each the same poses.
    folders: list[tuple[Path, Callable[[], Pile], str, int | None, int]] = []
    paths = iter(job_folders(root, spec, s))
    if spec.write_real:
        folders.append((next(paths), the_real_pile, "real", light_id, light_id))
    for v, path in zip(spec.variants, paths, strict=True):

        def pile(v: int = v) -> Pile:
            return the_real_pile() if v <= 15 else new_pile(np.random.default_rng([spec.seed, s, v]))

        real_light = v == 0 or 16 <= v <= 30
        lid = light_id if real_light else None
        sim_domain = "randomised" if spec.appearance == "randomised" else "sim"
        folders.append((path, pile, sim_domain, lid, light_id if real_light else 100 + v))
    written = 0
    for path, pile, domain, lid, light_value in folders:
        if scene_done(path):
            continue
        written += _write_folder(
            root, path.parent.name, path.name, pile(), domain, lid, {**info, "light": light_value}, spec, meshes,
            [spec.seed, s],
        )  # fmt: skip
    return written


def _write_folder(root, camera, name, pile: Pile, domain, light_id, info, spec: DimoSpec, meshes, key) -> int:
    folder_rng = np.random.default_rng([*key, zlib.crc32(f"{camera}/{name}".encode())])  # stable across runs
    final = Path(root) / camera / name
    sheet_path = Path(root) / "contact_sheets" / f"{camera}_{name}.png"
    with scene_folder(final, extra=[sheet_path]) as tmp:
        if tmp is None:
            return 0
        # fx scales with the width so that other image sizes keep DIMO small's field of view.
        fx = RIG_FX * spec.width / 320
        rig = dimo_rig(spec.n_viewpoints, width=spec.width, height=spec.height, fx=fx, target=RIG_TARGET)
        cams = [(K, T) for _, K, T in rig]
        centre = pile.T_world_model[:, :3, 3].mean(axis=0)
        style = make_style(folder_rng, domain, len(pile.obj_ids), centre, light_id=light_id, carrier_index=0)
        views = render_views(
            meshes.many(pile.obj_ids), pile.T_world_model, cams, spec.height, spec.width, style, folder_rng
        )
        scene_camera, scene_gt, scene_info = {}, {}, {}
        for (vid, K, T_cw), view in zip(rig, views, strict=True):
            write_image(tmp / "rgb" / f"{vid:06d}.png", view.rgb)
            scene_camera[vid] = camera_entry(K, T_cw, with_c2w=True)
            scene_gt[vid] = [gt_entry(pile.obj_ids[i], T_cw @ pile.T_world_model[i]) for i in pile.gt_indices]
            scene_info[vid] = {**info, "viewpoint": vid}
        world = [
            {
                "obj_id": int(pile.obj_ids[i]),
                "cam_R_m2w": [float(x) for x in pile.T_world_model[i, :3, :3].ravel()],
                "cam_t_m2w": [float(x) for x in pile.T_world_model[i, :3, 3]],
            }
            for i in pile.gt_indices
        ]
        save_json(tmp / SCENE_CAMERA, scene_camera)
        save_json(tmp / SCENE_GT, scene_gt)
        save_json(tmp / "scene_gt_world.json", world)
        save_json(tmp / "scene_info.json", scene_info)
        if spec.contact_sheets:
            write_contact_sheet(sheet_path, views)
    return 1
