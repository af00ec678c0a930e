"""Write a synthetic dataset in exactly the T-LESS BOP layout (docs/datasets.md, "T-LESS and other BOP datasets").

The full BOP set: ``models_cad/`` + ``models_eval/``, ``camera_primesense.json``,
``test_primesense/{scene:06d}/`` (PNG 720x540, 16-bit depth with depth_scale 0.1, ``mask/``,
``mask_visib/``, ``scene_camera.json`` with per-image K and w2c, ``scene_gt.json``,
``scene_gt_info.json``) for static piles seen by per-image cameras, ``train_pbr/{scene:06d}/``
(JPG; objects re-dropped every ``drop_every`` images, as BOP's PBR renders), and
``test_targets_bop19.json`` (the visib_fract >= 0.1 rule). The table the objects rest on is
rendered (it occludes and casts shadows) but is not a BOP object.

As real T-LESS, a dataset has one catalogue of 30 objects (:mod:`bop_cender.synth.catalogue`: families
of similar-looking parts of different sizes), fixed by ``TlessSpec.catalogue_seed``; each pile shows a
few of them (``models_per_scene``), some several times, drawn with the scene's poses, light and
materials from ``TlessSpec.seed``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bop_cender.data.bop_io import load_json, save_depth, save_json, write_image
from bop_cender.data.layout import MIN_VISIB_FRACT, SCENE_GT, SCENE_GT_INFO, TARGETS_FILE, TARGETS_FILE_BOP24
from bop_cender.meshes import MeshCache
from bop_cender.synth.bop_files import Pile, camera_entry, gt_entry, make_pile, scene_folder
from bop_cender.synth.catalogue import N_OBJECTS, catalogue_parts
from bop_cender.synth.contact_sheet import write_contact_sheet
from bop_cender.synth.gt_info import object_visibility
from bop_cender.synth.imaging import render_views
from bop_cender.synth.models_info import write_model_folders
from bop_cender.synth.parts import Part, make_carrier
from bop_cender.synth.piles import PileGeometryCache
from bop_cender.synth.rigs import TLESS_FX, TLESS_FY, TLESS_WIDTH, tless_cameras
from bop_cender.synth.styles import check_appearance, make_style

DEPTH_SCALE = 0.1
#: The split's camera file at the dataset root.
CAMERA_FILE = "camera_primesense.json"
#: Views on a scene's contact sheet (the first ones rendered).
SHEET_VIEWS = 4
TABLE_ID = 0  # render-only support; never written to GT files
#: The T-LESS layout's one object catalogue (any fixed value; 2017 is T-LESS's year).
TLESS_CATALOGUE_SEED = 2017


@dataclass(frozen=True)
class TlessSpec:
    """What to generate.

    Attributes:
        n_scenes: test scenes (ids 1..n, as T-LESS numbers them).
        n_views: images per test scene.
        objects_per_scene: (min, max) instances per pile (a test scene, or a PBR drop).
        models_per_scene: (min, max) distinct catalogue objects a pile's instances are drawn from (a real
            T-LESS test scene shows a few of the 30 objects, some several times). The piles' size, hence
            the cost of a scene, does not depend on the catalogue's size.
        pbr_scenes, pbr_images: ``train_pbr`` scenes (ids 0..) and images per scene.
        drop_every: PBR objects are re-dropped every this many images.
        seed: scenes, poses, light and materials derive from it (not the models: see ``catalogue_seed``).
        catalogue_seed: draws the 30 objects (:func:`tless_models`). Fixed per layout, as a real dataset
            has one catalogue, so that sets of other seeds share their objects (a network trained on one
            is tested on another).
        appearance: ``default`` (``train_pbr`` as BOP's PBR renders: plastic of random colours, random
            lights) or ``randomised`` (plastic of any colour and finish, lights, environment, table (hidden
            from half the piles), background and sensor drawn wide: domain randomisation; see
            :mod:`bop_cender.synth.styles`). The test folders keep T-LESS's look either way.
    """

    n_scenes: int = 2
    n_views: int = 10
    objects_per_scene: tuple[int, int] = (5, 8)
    models_per_scene: tuple[int, int] = (3, 5)
    pbr_scenes: int = 1
    pbr_images: int = 4
    drop_every: int = 25
    width: int = 720
    height: int = 540
    seed: int = 0
    contact_sheets: bool = True
    catalogue_seed: int = TLESS_CATALOGUE_SEED
    appearance: str = "default"

    def __post_init__(self) -> None:
        check_appearance(self.appearance)
        for name in ("objects_per_scene", "models_per_scene"):
            lo, hi = getattr(self, name)
            if not 1 <= lo <= hi:
                raise ValueError(f"{name} must be (min, max) with 1 <= min <= max, got {(lo, hi)}")
        if self.models_per_scene[1] > N_OBJECTS:
            raise ValueError(f"models_per_scene: the catalogue has {N_OBJECTS} objects, got {self.models_per_scene}")
        if self.seed < 0 or self.catalogue_seed < 0:
            raise ValueError(f"seeds must be >= 0, got seed {self.seed}, catalogue_seed {self.catalogue_seed}")


def tless_models(catalogue_seed: int = TLESS_CATALOGUE_SEED) -> dict[int, Part]:
    """The catalogue: 30 objects (ids 1..30, families of one part type at 2-4 sizes, see
    :mod:`bop_cender.synth.catalogue`) and the render-only table (id 0), drawn by ``catalogue_seed``."""
    models = catalogue_parts(catalogue_seed)
    models[TABLE_ID] = make_carrier(np.random.default_rng([catalogue_seed, 9]), (600.0, 450.0, 30.0))
    return models


def write_models(root: Path, spec: TlessSpec) -> dict[int, Part]:
    """Write ``models_cad/``, ``models_eval/`` and ``camera_primesense.json`` once; return the models."""
    models = tless_models(spec.catalogue_seed)
    root = Path(root)
    write_model_folders(root, {i: p for i, p in models.items() if i != TABLE_ID}, "tless")
    if not (root / CAMERA_FILE).is_file():
        scale = spec.width / TLESS_WIDTH  # the images' own intrinsics (rigs.tless_cameras) at this size
        cam = {"cx": spec.width / 2, "cy": spec.height / 2, "depth_scale": DEPTH_SCALE, "fx": TLESS_FX * scale,
               "fy": TLESS_FY * scale}  # fmt: skip
        save_json(root / CAMERA_FILE, {**cam, "height": spec.height, "width": spec.width})
    return models


def scene_jobs(spec: TlessSpec) -> list[tuple[str, int]]:
    """Independent units of work: ``("test", scene_id)`` and ``("pbr", scene_id)``."""
    return [("test", s + 1) for s in range(spec.n_scenes)] + [("pbr", s) for s in range(spec.pbr_scenes)]


def job_folders(root: Path, job: tuple[str, int]) -> list[Path]:
    """The scene folder a job writes: ``test_primesense/{s:06d}`` or ``train_pbr/{s:06d}``."""
    kind, s = job
    return [Path(root) / ("test_primesense" if kind == "test" else "train_pbr") / f"{s:06d}"]


def write_scene(
    root: Path,
    spec: TlessSpec,
    job: tuple[str, int],
    models: dict[int, Part],
    meshes: MeshCache,
    piles: PileGeometryCache | None = None,
) -> int:
    """Write one test or PBR scene folder (skipped if it is done, :mod:`bop_cender.synth.done`). Returns folders
    written."""
    kind, s = job
    split = "test_primesense" if kind == "test" else "train_pbr"
    rng = np.random.default_rng([spec.seed, 1 if kind == "test" else 2, s])
    object_ids = [i for i in models if i != TABLE_ID]
    sheet_path = Path(root) / "contact_sheets" / f"{split}_{s:06d}.png"
    with scene_folder(job_folders(root, job)[0], extra=[sheet_path]) as tmp:
        if tmp is None:
            return 0
        n_images = spec.n_views if kind == "test" else spec.pbr_images
        cameras = tless_cameras(n_images, rng, width=spec.width, height=spec.height)
        records: dict[str, dict] = {"scene_camera": {}, "scene_gt": {}, "scene_gt_info": {}}
        sheet = []
        step = n_images if kind == "test" else spec.drop_every
        for start in range(0, n_images, step):
            lo, hi = spec.objects_per_scene
            n = int(rng.integers(lo, hi + 1))
            k = min(int(rng.integers(spec.models_per_scene[0], spec.models_per_scene[1] + 1)), len(object_ids))
            shown = sorted(int(i) for i in rng.choice(object_ids, size=k, replace=False))
            pile = make_pile(
                models, shown, TABLE_ID, models[TABLE_ID], n, "mixed", rng, support_in_gt=False, cache=piles
            )
            ids = range(start, min(start + step, n_images))
            views = _write_images(tmp, kind, pile, [cameras[i] for i in ids], list(ids), spec, rng, meshes, records)
            sheet += views[: max(0, SHEET_VIEWS - len(sheet))]  # keep only what the contact sheet shows
        for name, content in records.items():
            save_json(tmp / f"{name}.json", content)
        if spec.contact_sheets:
            write_contact_sheet(sheet_path, sheet, SHEET_VIEWS)
    return 1


def _write_images(tmp: Path, kind, pile: Pile, cameras, im_ids, spec: TlessSpec, rng, meshes, records) -> list:
    if kind == "test":
        domain = "tless"
    else:
        domain = "randomised" if spec.appearance == "randomised" else "pbr"
    mesh_list = meshes.many(pile.obj_ids)
    centre = pile.T_world_model[:, :3, 3].mean(axis=0)
    style = make_style(rng, domain, len(pile.obj_ids), centre, carrier_index=0, surface="plastic")
    views = render_views(mesh_list, pile.T_world_model, cameras, spec.height, spec.width, style, rng)
    ext = "png" if kind == "test" else "jpg"
    for im_id, (K, T_cw), view in zip(im_ids, cameras, views, strict=True):
        T_cm = np.einsum("ij,mjk->mik", T_cw, pile.T_world_model)
        vis = object_visibility(mesh_list, T_cm, K, view.instance, view.depth, pile.gt_indices)
        write_image(tmp / "rgb" / f"{im_id:06d}.{ext}", view.rgb)
        save_depth(tmp / "depth" / f"{im_id:06d}.png", view.depth, DEPTH_SCALE)
        for gt_id, v in enumerate(vis):
            write_image(tmp / "mask" / f"{im_id:06d}_{gt_id:06d}.png", v.mask.astype(np.uint8) * 255)
            write_image(tmp / "mask_visib" / f"{im_id:06d}_{gt_id:06d}.png", v.mask_visib.astype(np.uint8) * 255)
        eye = -T_cw[:3, :3].T @ T_cw[:3, 3]
        elev = int(round(np.degrees(np.arcsin((eye - centre)[2] / np.linalg.norm(eye - centre)))))
        records["scene_camera"][im_id] = camera_entry(
            K, T_cw, with_c2w=False, depth_scale=DEPTH_SCALE, **({"elev": elev, "mode": 0} if kind == "test" else {})
        )
        records["scene_gt"][im_id] = [gt_entry(pile.obj_ids[i], T_cm[i]) for i in pile.gt_indices]
        records["scene_gt_info"][im_id] = [v.info for v in vis]
    return views


def write_targets(
    root: Path, split_folder: str = "test_primesense", gt_file: str = SCENE_GT, info_file: str = SCENE_GT_INFO
) -> int:
    """Write ``test_targets_bop19.json`` from the test scenes on disk (visib_fract >= 0.1 rule), and
    ``test_targets_bop24.json``: the images of those targets (the 6D-detection task's file lists images only).

    Reads back ``scene_gt.json`` / ``scene_gt_info.json`` (``gt_file`` / ``info_file``: a multi-sensor split's
    evaluated sensor's) of ``split_folder`` so that a resumed run gives the same file. Returns the number of targets.
    """
    targets = []
    test_dir = Path(root) / split_folder
    for scene_dir in sorted(p for p in test_dir.iterdir() if p.is_dir() and p.name.isdigit()):
        gt = load_json(scene_dir / gt_file, keys_to_int=True)
        info = load_json(scene_dir / info_file, keys_to_int=True)
        for im_id in sorted(gt):
            counts: dict[int, int] = {}
            for g, i in zip(gt[im_id], info[im_id], strict=True):
                if i["visib_fract"] >= MIN_VISIB_FRACT:
                    counts[g["obj_id"]] = counts.get(g["obj_id"], 0) + 1
            targets += [
                {"im_id": im_id, "inst_count": c, "obj_id": o, "scene_id": int(scene_dir.name)}
                for o, c in sorted(counts.items())
            ]
    save_json(Path(root) / TARGETS_FILE, targets)
    images = dict.fromkeys((t["scene_id"], t["im_id"]) for t in targets)
    save_json(Path(root) / TARGETS_FILE_BOP24, [{"im_id": im, "scene_id": scene} for scene, im in images])
    return len(targets)
