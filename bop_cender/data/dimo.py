"""The DIMO loader: splits, the paper's image selection, and typed scenes with checked poses.

Layout (docs/datasets.md, "DIMO"): ``<root>/models/`` (BOP models, ids >= 100
are carriers/background), ``<root>/real_<camera>/<NNNNNN>/`` real scenes and
``<root>/sim_<camera>/<NNNNNN_VV>/`` synthetic variants of them. DIMO stores camera-to-world
poses; they are inverted here, once, so every :class:`CameraView` holds ``T_cam_world``.

Opening a split reads only ``models_info.json`` and each scene folder's ``scene_info.json`` (to
apply the selection); the other files of a scene are read and cross-checked when the scene is
first asked for (``Dataset.scene(key)``).
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bop_cender.data.bop_io import check_same_image_ids, image_size, load_image_dict, require_dir
from bop_cender.data.consistency import ResidualTracker
from bop_cender.data.dimo_files import (
    CAMERA_FILE,
    GT_FILE,
    GT_WORLD_FILE,
    INFO_FILE,
    check_scene_gt,
    dimo_image_dir,
    read_cameras,
    read_gt_world,
    read_scene_info,
    rgb_path,
)
from bop_cender.data.models import load_models
from bop_cender.data.split_size import SAMPLE_SCENES, SAMPLE_VIEWS_PER_SCENE, vote_image_size
from bop_cender.data.types import CameraView, Dataset, GtObject, ObjectModel, Scene
from bop_cender.errors import ConfigError, DatasetError

__all__ = [
    "CARRIER_MIN_ID",
    "PAPER_SELECTION",
    "SPLITS",
    "DimoFolder",
    "DimoSelection",
    "dimo_image_dir",
    "list_dimo_scenes",
    "load_dimo_scene",
    "open_dimo",
]

#: The user's split names: ``real`` (real_<camera>/), ``sim`` and ``train`` (sim_<camera>/ variants).
SPLITS = ("real", "sim", "train")
#: DIMO model ids from this one up are carriers/background: occluders, never pose targets.
CARRIER_MIN_ID = 100

_FOLDER = re.compile(r"^(\d+)(?:_(\d{2}))?$")


@dataclass(frozen=True)
class DimoSelection:
    """Which DIMO folders and images a split uses; the paper's choice is the default (appendix).

    A field set to None means "no filtering" on that criterion.

    Attributes:
        camera: camera folder suffix: ``real_<camera>/`` and ``sim_<camera>/``.
        carrier: ``scene_info`` carrier id to keep (paper: 2, the cardboard carrier).
        compositions: ``scene_info`` ``parts`` (composition) ids to keep (paper: 1, 2, 4, one
            object type per scene).
        viewpoints: viewpoint ids to keep (paper: 7 of the 13).
        sim_variants: variant suffixes of split ``sim`` (paper's synthetic test set: 00, the twin
            of each real scene with real lighting and poses).
        train_variants: variant suffixes of split ``train``: the random-pose variants. The paper
            writes 16-72, but DIMO's archives stop at 70 (``_31-71`` is half-open), so 16..70.
    """

    camera: str = "jaigo"
    carrier: int | None = 2
    compositions: tuple[int, ...] | None = (1, 2, 4)
    viewpoints: tuple[int, ...] | None = (0, 2, 4, 6, 8, 10, 12)
    sim_variants: tuple[int, ...] | None = (0,)
    train_variants: tuple[int, ...] | None = tuple(range(16, 71))

    def __post_init__(self) -> None:
        for name in ("compositions", "viewpoints", "sim_variants", "train_variants"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, tuple(sorted({int(v) for v in value})))

    @classmethod
    def everything(cls, camera: str = "jaigo") -> DimoSelection:
        """No filtering: every carrier, composition, viewpoint and variant (splits sim and train alike)."""
        return cls(camera, None, None, None, None, None)

    def variants(self, split: str) -> tuple[int, ...] | None:
        """The variant suffixes of ``split`` (None: any; ``real`` folders have none)."""
        return {"sim": self.sim_variants, "train": self.train_variants}.get(split)

    def view_drop_reason(self, info: Mapping[str, Any]) -> str | None:
        """Why a view (its normalised ``scene_info`` entry) is not selected, or None if it is."""
        if self.carrier is not None and info["carrier"] != self.carrier:
            return "other carrier"
        if self.compositions is not None and info["parts"] not in self.compositions:
            return "other composition"
        if self.viewpoints is not None and info["viewpoint"] not in self.viewpoints:
            return "viewpoint not selected"
        return None

    def describe(self, split: str) -> str:
        """One line for ``bop-cender info``."""
        parts = [
            f"carrier {_fmt_any(None if self.carrier is None else (self.carrier,))}",
            f"compositions {_fmt_any(self.compositions)}",
            f"viewpoints {_fmt_any(self.viewpoints)}",
        ]
        if split != "real":
            parts.append(f"variants {_fmt_any(self.variants(split), width=2)}")
        return f"selection ({split}, {_camera_folder(split, self.camera)}/): " + ", ".join(parts)


#: The paper's selection (appendix: carrier 2, compositions 1, 2, 4, viewpoints 0, 2, ..., 12).
PAPER_SELECTION = DimoSelection()


@dataclass(frozen=True)
class DimoFolder:
    """A scene folder that passed the selection, and the image ids it keeps.

    Attributes:
        scene_id: folder name (``000123`` or ``000123_17``), the Scene's id and key.
        path: the folder.
        number: scene number (123).
        variant: synthetic variant suffix (17), None for a plain folder.
        im_ids: selected image ids, sorted.
    """

    scene_id: str
    path: Path
    number: int
    variant: int | None
    im_ids: tuple[int, ...]


def open_dimo(root: str | Path, split: str, selection: DimoSelection = PAPER_SELECTION) -> Dataset:
    """Open one DIMO split: models, the selected scene folders and their selected images.

    Args:
        root: the DIMO root (``dimo/`` or ``dimo_small/``), holding ``models/`` and the camera folders.
        split: ``real`` (``real_<camera>/``), ``sim`` (``sim_<camera>/``, variants
            ``selection.sim_variants``) or ``train`` (``sim_<camera>/``, ``selection.train_variants``).
        selection: which folders and images to keep; default the paper's.

    Returns:
        A :class:`Dataset` named ``dimo`` whose scenes load lazily (see :func:`load_dimo_scene`);
        ``selection`` holds notes on what was kept and why the rest was dropped; ``residuals``
        fills with the largest pose-consistency residuals as scenes load.

    Raises:
        ConfigError: unknown split.
        DatasetError: missing or malformed files, or no folder passes the selection.
    """
    if split not in SPLITS:
        raise ConfigError(f"unknown DIMO split {split!r}; expected one of {', '.join(SPLITS)}", field="--split")
    root = require_dir(root, "DIMO root folder")
    models = load_models(root / "models", is_target=lambda obj_id: obj_id < CARRIER_MIN_ID)
    camera_dir = root / _camera_folder(split, selection.camera)
    folders, notes = list_dimo_scenes(camera_dir, split, selection)
    targets = [i for i, m in models.items() if m.is_target]
    carriers = [i for i, m in models.items() if not m.is_target]
    notes.append(
        f"models: target ids {_fmt_ids(targets) or 'none'}; carrier/background ids (>= {CARRIER_MIN_ID})"
        f" {_fmt_ids(carriers) or 'none'}, loaded as occluders, never targets"
    )
    if (root / "models_eval").is_dir():  # bop-cender synth writes one (a copy of models/); real DIMO has none
        notes.append("models_eval/ is not part of DIMO's layout and is not read: evaluation uses the models/ meshes")
    else:
        notes.append("DIMO has no models_eval/: evaluation uses the models/ meshes")
    residuals: dict[str, float] = {}
    loader = _SceneLoader(split=split, folders={f.scene_id: f for f in folders}, models=models, residuals=residuals)
    return Dataset(
        root=root,
        name="dimo",
        split=split,
        models=models,
        eval_models=dict(models),
        scene_keys=[f.scene_id for f in folders],
        loader=loader,
        selection=notes,
        residuals=residuals,
        image_size=_split_image_size(folders),
        has_depth=False,
        split_dir=camera_dir,
    )


def list_dimo_scenes(
    camera_dir: Path, split: str, selection: DimoSelection = PAPER_SELECTION
) -> tuple[list[DimoFolder], list[str]]:
    """The scene folders of ``camera_dir`` that ``split`` and ``selection`` keep, sorted by (scene, variant).

    Reads only each candidate folder's ``scene_info.json``. A view is kept if its carrier,
    composition (``parts``) and viewpoint pass the selection; a folder if it keeps any view.

    Returns:
        The kept folders and human-readable notes: folders found and kept, counts of dropped
        folders per reason, views kept and the viewpoints they cover.
    """
    if not camera_dir.is_dir():
        raise DatasetError(
            f"camera folder not found; split {split!r} expects <root>/{camera_dir.name}/<scene>/", file=camera_dir
        )
    parsed, folder_drops = _parse_folder_names(camera_dir)
    variants = selection.variants(split)
    kept: list[DimoFolder] = []
    view_drops: Counter[str] = Counter()
    n_views = 0
    viewpoints: set[int] = set()
    for number, variant, path in parsed:
        reason = _variant_drop_reason(split, variant, variants)
        if reason is not None:
            folder_drops[reason] += 1
            continue
        info = read_scene_info(path / INFO_FILE)
        reasons = {im_id: selection.view_drop_reason(entry) for im_id, entry in info.items()}
        im_ids = tuple(i for i, r in reasons.items() if r is None)
        if not im_ids:
            folder_drops[" + ".join(sorted({r for r in reasons.values() if r})) or "no images"] += 1
            continue
        n_views += len(info)
        view_drops.update(r for r in reasons.values() if r)
        viewpoints.update(info[i]["viewpoint"] for i in im_ids)
        kept.append(DimoFolder(path.name, path, number, None if variant < 0 else variant, im_ids))
    found = len(parsed) + folder_drops["not a scene folder name (NNNNNN or NNNNNN_VV)"]
    notes = [
        selection.describe(split),
        f"folders: {found} found in {camera_dir.name}/, {len(kept)} kept",
    ]
    if folder_drops:
        notes.append("folders dropped: " + _fmt_counts(folder_drops))
    n_kept = sum(len(f.im_ids) for f in kept)
    views = f"views: {n_kept} of {n_views} kept in kept folders, viewpoints {_fmt_ids(sorted(viewpoints)) or 'none'}"
    notes.append(views + (f"; dropped: {_fmt_counts(view_drops)}" if view_drops else ""))
    if not kept:
        raise DatasetError(f"no scene folder passes the selection ({'; '.join(notes)})", file=camera_dir)
    return kept, notes


def load_dimo_scene(
    scene_dir: Path,
    split: str,
    im_ids: Iterable[int] | None,
    models: Mapping[int, ObjectModel],
    residuals: dict[str, float] | None = None,
) -> Scene:
    """Read and cross-check one DIMO scene folder; keep the views ``im_ids`` (None: all).

    Checks: the image ids of scene_camera, scene_gt and scene_info agree; every image's
    scene_gt lists the objects of scene_gt_world in order; each obj_id is a known model;
    ``T_cam_model == T_cam_world @ T_world_model`` and, where both are stored, w2c == inv(c2w)
    (warn above 0.1 mm / 1e-4 rad, fail above 5 mm / 0.01 rad); each kept view has its rgb PNG.

    Args:
        residuals: if given, updated with the largest residuals (``gt_max_mm``, ``gt_max_rad``,
            ``cam_max_mm``, ``cam_max_rad``) and pair counts (``gt_pairs``, ``cam_pairs``).

    Returns:
        A :class:`Scene` with the kept views sorted by image id and one :class:`GtObject` per
        ``scene_gt_world.json`` entry (carriers included), ``gt_ids[im_id]`` = its index in that
        image's scene_gt list.
    """
    scene_dir = Path(scene_dir)
    paths = {name: scene_dir / name for name in (CAMERA_FILE, GT_FILE, GT_WORLD_FILE, INFO_FILE)}
    cam_tracker, gt_tracker = ResidualTracker(), ResidualTracker()
    cameras = read_cameras(paths[CAMERA_FILE], cam_tracker)
    world = read_gt_world(paths[GT_WORLD_FILE], models.keys())
    info = read_scene_info(paths[INFO_FILE])
    scene_gt = load_image_dict(paths[GT_FILE])
    check_same_image_ids({paths[CAMERA_FILE]: cameras, paths[GT_FILE]: scene_gt, paths[INFO_FILE]: info})
    stored = check_scene_gt(paths[GT_FILE], scene_gt, world, cameras, gt_tracker)
    cam_tracker.report(f"{paths[CAMERA_FILE]}: cam_*_w2c vs inverted cam_*_c2w")
    gt_tracker.report(f"{paths[GT_FILE]} vs {CAMERA_FILE} and {GT_WORLD_FILE}")
    if residuals is not None:
        _merge_residuals(residuals, "cam", cam_tracker)
        _merge_residuals(residuals, "gt", gt_tracker)

    selected = sorted(cameras) if im_ids is None else sorted(set(im_ids))
    for im_id in selected:
        if im_id not in cameras:
            raise DatasetError(f"selected image {im_id} is not in the file", file=paths[CAMERA_FILE], field="image ids")
    views = []
    for im_id in selected:
        path = rgb_path(scene_dir, im_id)
        width, height = image_size(path)
        cam = cameras[im_id]
        views.append(
            CameraView(
                im_id=im_id,
                K=cam.K,
                T_cam_world=cam.T_cam_world,
                width=width,
                height=height,
                rgb_path=path,
                info=info[im_id],
                source=str(paths[CAMERA_FILE]),
            )
        )
    gt = tuple(
        GtObject(
            obj.obj_id,
            obj.T_world_model,
            gt_ids={i: k for i in selected},
            T_cam_model={i: stored[i][k] for i in selected},
            source=str(paths[GT_WORLD_FILE]),
        )  # fmt: skip
        for k, obj in enumerate(world)
    )
    m = re.match(r"^\d+_(\d{2})$", scene_dir.name)
    scene_info = {
        "carrier": _common(info[i]["carrier"] for i in selected),
        "composition": _common(info[i]["parts"] for i in selected),
        "variant": int(m.group(1)) if m else None,
    }
    return Scene(dataset="dimo", split=split, scene_id=scene_dir.name, views=tuple(views), gt=gt, info=scene_info)


@dataclass
class _SceneLoader:
    """``Dataset.loader``: loads a kept folder with its kept images, feeding the shared residuals."""

    split: str
    folders: dict[str, DimoFolder]
    models: dict[int, ObjectModel]
    residuals: dict[str, float]

    def __call__(self, key: str) -> Scene:
        folder = self.folders[key]
        return load_dimo_scene(folder.path, self.split, folder.im_ids, self.models, self.residuals)


def _camera_folder(split: str, camera: str) -> str:
    return f"{'real' if split == 'real' else 'sim'}_{camera}"


def _parse_folder_names(camera_dir: Path) -> tuple[list[tuple[int, int, Path]], Counter[str]]:
    """Sub-folders as (scene number, variant or -1, path), sorted; other names counted, not parsed."""
    parsed: list[tuple[int, int, Path]] = []
    drops: Counter[str] = Counter()
    for path in camera_dir.iterdir():
        if not path.is_dir():
            continue
        m = _FOLDER.match(path.name)
        if m is None:
            drops["not a scene folder name (NNNNNN or NNNNNN_VV)"] += 1
            continue
        parsed.append((int(m.group(1)), -1 if m.group(2) is None else int(m.group(2)), path))
    parsed.sort(key=lambda item: (item[0], item[1], item[2].name))
    return parsed, drops


def _variant_drop_reason(split: str, variant: int, variants: tuple[int, ...] | None) -> str | None:
    if split == "real":
        return "variant folder (NNNNNN_VV) in a real camera folder" if variant >= 0 else None
    if variant < 0:
        return "no variant suffix (a real-style folder in a sim folder)"
    if variants is not None and variant not in variants:
        return f"variant not in split {split}"
    return None


def _split_image_size(folders: Sequence[DimoFolder]) -> tuple[int, int] | None:
    """(width, height) most of the first views of the first selected folders share
    (:func:`bop_cender.data.split_size.vote_image_size`: one wrong-sized first image is not the reference),
    None where none of them exists (the scene load reports it)."""
    paths = [
        rgb_path(folder.path, im_id)
        for folder in folders[:SAMPLE_SCENES]
        for im_id in folder.im_ids[:SAMPLE_VIEWS_PER_SCENE]
    ]
    voted = vote_image_size(paths)
    return None if voted is None else voted.size


def _merge_residuals(residuals: dict[str, float], prefix: str, tracker: ResidualTracker) -> None:
    residuals[f"{prefix}_max_mm"] = max(residuals.get(f"{prefix}_max_mm", 0.0), tracker.max_mm)
    residuals[f"{prefix}_max_rad"] = max(residuals.get(f"{prefix}_max_rad", 0.0), tracker.max_rad)
    residuals[f"{prefix}_pairs"] = residuals.get(f"{prefix}_pairs", 0.0) + float(tracker.count)


def _common(values: Iterable[int]) -> int | tuple[int, ...] | None:
    """The one value all kept views share (DIMO: per scene), or the sorted distinct values if mixed."""
    distinct = sorted(set(values))
    if not distinct:
        return None
    return distinct[0] if len(distinct) == 1 else tuple(distinct)


def _fmt_ids(ids: Sequence[int], width: int = 0) -> str:
    """``0, 2, 4`` or ``16-70`` (runs of 3+ consecutive ids collapsed)."""
    ids = sorted(ids)
    out: list[str] = []
    i = 0
    while i < len(ids):
        j = i
        while j + 1 < len(ids) and ids[j + 1] == ids[j] + 1:
            j += 1
        if j - i >= 2:
            out.append(f"{ids[i]:0{width}d}-{ids[j]:0{width}d}")
        else:
            out.extend(f"{v:0{width}d}" for v in ids[i : j + 1])
        i = j + 1
    return ", ".join(out)


def _fmt_any(ids: Sequence[int] | None, width: int = 0) -> str:
    return "any" if ids is None else _fmt_ids(ids, width)


def _fmt_counts(counts: Counter[str]) -> str:
    return ", ".join(f"{n} {reason}" for reason, n in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))
