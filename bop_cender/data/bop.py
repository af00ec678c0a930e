"""Open any dataset in the BOP scenewise layout as typed, lazily loaded multi-view scenes.

What happens at open time (cheap: one ``scene_camera.json`` per scene folder, the targets file,
``models_info.json`` and one image header):

1. The split folder is resolved (``test`` -> ``test_primesense/`` when that is the only match).
2. The models (``models/`` or ``models_{type}/``) and evaluation models (``models_eval/``) load.
3. ``test_targets_bop19.json`` (test splits only) selects the images: only target images are used.
4. Every scene folder's images are cut into Scenes (see :func:`group_views`):

   - test-like splits: per folder, the (target) images sorted by id, shuffled with
     ``np.random.default_rng([seed, scene_int])`` and cut into consecutive groups of ``n_views``
     (the last group may be smaller). Every image is in exactly one group; key ``000001/g03``.
   - ``*pbr*`` splits: objects are re-dropped every 25 images, so one Scene per image
     (key ``000001/i000042``). The same holds for a folder where an image has no
     ``cam_R_w2c``/``cam_t_w2c``: without camera poses views cannot be related.

Reading ``scene_gt.json``/``scene_gt_info.json``, the consistency checks and the file checks
happen lazily, per scene folder, in :class:`bop_cender.data.bop_scene.BopSceneLoader`.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bop_cender.data.bop_io import as_int, as_number, load_image_dict, load_json, require_dir, require_keys
from bop_cender.data.bop_scene import (
    IMAGE_SUFFIXES,
    RGB_FOLDERS,
    BopSceneLoader,
    ScenePlan,
)
from bop_cender.data.layout import SCENE_CAMERA, TARGETS_FILE, TARGETS_FILE_BOP24
from bop_cender.data.models import load_models
from bop_cender.data.scene_ids import scene_folder_to_int
from bop_cender.data.split_size import SAMPLE_SCENES, SAMPLE_VIEWS_PER_SCENE, vote_image_size
from bop_cender.data.targets_file import check_not_repeated, image_selection
from bop_cender.data.types import Dataset, ObjectModel
from bop_cender.errors import ConfigError, DatasetError, DatasetWarning

#: Views per multi-view group: the paper's 5 (CosyPose reported 4 and 8).
DEFAULT_N_VIEWS = 5
EVAL_MODELS_DIR = "models_eval"


@dataclass(frozen=True)
class SplitLayout:
    """Where one split's files are, and what is known about them before any scene is read.

    Attributes:
        folder: split folder under the root (``test_primesense``, ``train_pbr``).
        camera_file: root camera file whose ``width``/``height`` describe this split's images
            (``camera_primesense.json``), or None when none does.
        image_size: ``(width, height)`` known for the split when no camera file says it.
        models_dir: models folder (``models``, ``models_cad``).
        eval_models_dir: evaluation models folder; the models folder is used when it is absent.
    """

    folder: str
    camera_file: str | None = None
    image_size: tuple[int, int] | None = None
    models_dir: str = "models"
    eval_models_dir: str = EVAL_MODELS_DIR

    @property
    def is_pbr(self) -> bool:
        """Physically-based renders: objects re-dropped every 25 images, so one Scene per image."""
        return "pbr" in self.folder

    @property
    def is_test(self) -> bool:
        return self.folder.startswith("test")


def open_bop(
    root: str | Path,
    split: str,
    *,
    name: str | None = None,
    n_views: int | None = None,
    seed: int = 0,
    model_type: str | None = None,
    split_type: str | None = None,
) -> Dataset:
    """Open ``split`` of a BOP-layout dataset at ``root``.

    Args:
        root: dataset root (holds ``models*/``, split folders, ``camera*.json``).
        split: ``test``, ``train``, ... or a literal split folder name (``test_primesense``).
        name: dataset name as in BOP result file names; defaults to the root folder's name.
        n_views: views per multi-view group (default :data:`DEFAULT_N_VIEWS`).
        seed: seed of the view-grouping shuffle.
        model_type: use ``models_{model_type}/`` instead of ``models/``.
        split_type: use the folder ``{split}_{split_type}`` (e.g. ``primesense``).

    Raises:
        ConfigError: unknown split, split type or model type (the message lists what exists).
        DatasetError: missing or inconsistent files.
    """
    root = _require_root(root)
    folder = resolve_split_folder(root, split, split_type)
    camera_file = _camera_file(root, folder)
    models_dir = f"models_{model_type}" if model_type else "models"
    layout = SplitLayout(folder=folder, camera_file=camera_file, models_dir=models_dir)
    return open_bop_split(root, name or root.resolve().name, split, layout, n_views=n_views, seed=seed)


def open_bop_split(
    root: str | Path,
    name: str,
    split: str,
    layout: SplitLayout,
    *,
    n_views: int | None = None,
    seed: int = 0,
) -> Dataset:
    """Open one split whose folder and constants are already known (used by dataset specialisations).

    Args:
        root: dataset root.
        name: dataset name (``tless``).
        split: the user's split name, recorded in the Dataset and its Scenes.
        layout: where the split's files are.
        n_views: views per multi-view group (default 5).
        seed: seed of the view-grouping shuffle.
    """
    root = _require_root(root)
    n_views = DEFAULT_N_VIEWS if n_views is None else n_views
    if isinstance(n_views, bool) or not isinstance(n_views, int | np.integer) or n_views < 1:
        raise ConfigError(f"expected a positive integer, got {n_views!r}", field="--n-views")
    split_dir = root / layout.folder
    if not split_dir.is_dir():
        raise ConfigError(
            f"split folder {layout.folder}/ not found; split folders: {_split_folders(root)}",
            file=root,
            field="--split",
        )
    notes = [f"split {split!r}: folder {layout.folder}/"]
    models, eval_models = load_model_sets(root, layout, notes)

    scene_ids = scene_folders(split_dir)
    index = {sid: _camera_index(split_dir / sid / SCENE_CAMERA) for sid in scene_ids}
    selected = select_images(root, index, models, layout, notes)
    plans = _plan_scenes(selected, index, layout, n_views, seed, notes)
    camera = _read_camera_file(root, layout)
    size, has_depth = _image_size(split_dir, layout, camera, index, notes)
    residuals: dict[str, float] = {}
    loader = BopSceneLoader(
        dataset=name,
        split=split,
        split_dir=split_dir,
        plans=plans,
        obj_ids=frozenset(models),
        image_size=size,
        default_depth_scale=None if camera is None else camera.depth_scale,
        residuals=residuals,
    )
    return Dataset(
        root=root,
        name=name,
        split=split,
        models=models,
        scene_keys=list(plans),
        loader=loader,
        eval_models=eval_models,
        selection=notes,
        residuals=residuals,
        image_size=size,
        has_depth=has_depth,
        split_dir=split_dir,
    )


def select_images(
    root: Path, index: dict[str, dict[int, bool]], models: dict[int, ObjectModel], layout: SplitLayout, notes: list[str]
) -> dict[str, list[int]]:
    """The images of each scene folder a split uses (``index``: folder -> its image ids): a test split's target
    images (``test_targets_bop19.json``, and those ``test_targets_bop24.json`` adds; every image without either
    file), every image elsewhere. Scene folders without a selected image are left out.

    Raises:
        DatasetError: a targets file is malformed or names an image or object the split does not hold.
    """
    selected = {sid: sorted(ims) for sid, ims in index.items()}
    targets_path = root / TARGETS_FILE
    bop24_path = root / TARGETS_FILE_BOP24
    if layout.is_test and targets_path.is_file():
        selected = _read_targets(targets_path, index, models, layout.folder, notes)
    elif layout.is_test and not bop24_path.is_file():
        notes.append(f"no {TARGETS_FILE}: every image of every scene is used")
    if layout.is_test and bop24_path.is_file():  # BOP'24 detection scores these images: they are loaded too
        extra = image_selection(bop24_path, index, layout.folder)
        base = selected if targets_path.is_file() else {}
        selected = {sid: sorted(set(base.get(sid, ())) | extra.get(sid, set())) for sid in index
                    if sid in base or sid in extra}  # fmt: skip
        notes.append(f"BOP'24 targets ({TARGETS_FILE_BOP24}): their {sum(len(v) for v in extra.values())} images used")
    return selected


def group_views(im_ids: list[int], n_views: int, seed: int, scene_int: int) -> list[list[int]]:
    """Cut one scene's images into multi-view groups, CosyPose-style but with an explicit Generator.

    The ids are sorted, permuted by ``np.random.default_rng([seed, scene_int]).permutation`` and cut
    into consecutive chunks of ``n_views``; the last chunk may be smaller. Each chunk is returned
    sorted by id. Every image is in exactly one group; the result depends only on
    ``(im_ids, n_views, seed, scene_int)``, not on the order scenes are visited in.

    Returns:
        groups, each a sorted list of image ids.
    """
    ids = sorted(im_ids)
    order = np.random.default_rng([seed, scene_int]).permutation(len(ids))
    shuffled = [ids[i] for i in order]
    return [sorted(shuffled[k : k + n_views]) for k in range(0, len(shuffled), n_views)]


def resolve_split_folder(root: Path, split: str, split_type: str | None = None) -> str:
    """The split folder for ``split``: ``{split}_{split_type}``, ``{split}``, or the one ``{split}_*``.

    Raises:
        ConfigError: no such folder, or several ``{split}_*`` folders and no split type.
    """
    folders = _split_folders(root)
    if split_type:
        folder = f"{split}_{split_type}"
        if folder not in folders:
            raise ConfigError(f"split folder {folder}/ not found; split folders: {folders}", file=root, field="--split")
        return folder
    if split in folders:
        return split
    matches = [f for f in folders if f.startswith(f"{split}_")]
    if len(matches) == 1:
        return matches[0]
    if matches:
        raise ConfigError(
            f"split {split!r} is ambiguous ({', '.join(matches)}): give the folder as the split, e.g. --split {matches[0]}",
            file=root,
            field="--split",
        )
    raise ConfigError(f"unknown split {split!r}; split folders: {folders or 'none'}", file=root, field="--split")


def _require_root(root: str | Path) -> Path:
    return require_dir(root, "dataset root folder")


def _split_folders(root: Path) -> list[str]:
    """Folders at the root that can hold scenes: everything but ``models*`` and hidden ones."""
    return sorted(p.name for p in root.iterdir() if p.is_dir() and not p.name.startswith((".", "models", "__")))


def _camera_file(root: Path, folder: str) -> str | None:
    """``camera_{type}.json`` for a ``{split}_{type}`` folder when it exists, else ``camera.json``."""
    parts = folder.split("_", 1)
    candidates = [f"camera_{parts[1]}.json"] if len(parts) == 2 else []
    candidates.append("camera.json")
    return next((c for c in candidates if (root / c).is_file()), None)


def load_model_sets(
    root: Path, layout: SplitLayout, notes: list[str]
) -> tuple[dict[int, ObjectModel], dict[int, ObjectModel]]:
    """The models (``layout.models_dir``) and the evaluation models (``models_eval/``, else the same), noted."""
    models_dir = root / layout.models_dir
    if not models_dir.is_dir():
        found = sorted(p.name for p in root.iterdir() if p.is_dir() and p.name.startswith("models"))
        raise ConfigError(
            f"models folder {layout.models_dir}/ not found; models folders: {found or 'none'}"
            " (choose one with --model-type, e.g. --model-type cad for models_cad/)",
            file=root,
            field="--model-type",
        )
    models = load_models(models_dir)
    eval_dir = root / layout.eval_models_dir
    if eval_dir.is_dir() and eval_dir != models_dir:
        eval_models = load_models(eval_dir)
        missing = sorted(set(models) - set(eval_models))
        if missing:  # every object a scene may show is scored on its evaluation model
            raise DatasetError(
                f"object(s) {missing} of {layout.models_dir}/ have no evaluation model (every model needs one)",
                file=eval_dir / "models_info.json",
            )
        notes.append(f"models: {layout.models_dir}/; evaluation models: {layout.eval_models_dir}/")
    else:
        eval_models = models
        notes.append(
            f"models: {layout.models_dir}/; evaluation models: the same (no separate {layout.eval_models_dir}/)"
        )
    return models, eval_models


def scene_folders(split_dir: Path) -> list[str]:
    """Scene folder names, sorted by their int id; any other (non-hidden) folder is an error."""
    names = []
    for p in split_dir.iterdir():
        if not p.is_dir() or p.name.startswith("."):
            continue
        try:
            scene_folder_to_int(p.name)
        except ValueError:
            raise DatasetError("expected only scene folders named NNNNNN in a split folder", file=p) from None
        names.append(p.name)
    if not names:
        raise DatasetError("no scene folders (NNNNNN/) in this split folder", file=split_dir)
    return sorted(names, key=lambda s: (scene_folder_to_int(s), s))


def _camera_index(path: Path) -> dict[int, bool]:
    """Image ids of one scene and whether each has a world-to-camera pose (``cam_R_w2c``, ``cam_t_w2c``)."""
    entries = load_image_dict(path)
    index = {}
    for im_id, entry in entries.items():
        require_keys(entry, (), path, str(im_id))
        index[im_id] = "cam_R_w2c" in entry and "cam_t_w2c" in entry
    return index


def _read_targets(
    path: Path,
    index: dict[str, dict[int, bool]],
    models: dict[int, ObjectModel],
    folder: str,
    notes: list[str],
) -> dict[str, list[int]]:
    """Target image ids per scene folder from ``test_targets_bop19.json`` (scenes without targets dropped)."""
    entries = load_json(path)
    if not isinstance(entries, list) or not entries:
        got = f"{len(entries)} entries" if isinstance(entries, list) else type(entries).__name__
        raise DatasetError(f"expected a non-empty list of targets, got {got}", file=path)
    folders = {scene_folder_to_int(sid): sid for sid in index}
    selected: dict[str, set[int]] = {}
    first: dict[tuple[int, int, int], int] = {}
    for i, entry in enumerate(entries):
        where = f"[{i}]"
        require_keys(entry, ("scene_id", "im_id", "obj_id"), path, where)
        scene_int = as_int(entry["scene_id"], path, f"{where}.scene_id")
        im_id = as_int(entry["im_id"], path, f"{where}.im_id")
        obj_id = as_int(entry["obj_id"], path, f"{where}.obj_id")
        check_not_repeated(first, (scene_int, im_id, obj_id), i, path)
        if "inst_count" in entry and as_int(entry["inst_count"], path, f"{where}.inst_count") < 1:
            raise DatasetError(f"expected a positive inst_count, got {entry['inst_count']!r}", file=path, field=where)
        if scene_int not in folders:
            raise DatasetError(f"scene {scene_int} has no folder in {folder}/", file=path, field=f"{where}.scene_id")
        sid = folders[scene_int]
        if im_id not in index[sid]:
            raise DatasetError(
                f"image {im_id} is not in {folder}/{sid}/{SCENE_CAMERA}", file=path, field=f"{where}.im_id"
            )
        if obj_id not in models:
            raise DatasetError(f"object {obj_id} is not in the models", file=path, field=f"{where}.obj_id")
        selected.setdefault(sid, set()).add(im_id)
    n_images = sum(len(v) for v in selected.values())
    skipped = len(index) - len(selected)
    notes.append(
        f"BOP'19 targets ({TARGETS_FILE}): only target images are used: {n_images} images, {len(entries)} targets"
        f" in {len(selected)} scenes" + (f" ({skipped} scene folders without targets skipped)" if skipped else "")
    )
    return {sid: sorted(selected[sid]) for sid in index if sid in selected}


def _plan_scenes(
    selected: dict[str, list[int]],
    index: dict[str, dict[int, bool]],
    layout: SplitLayout,
    n_views: int,
    seed: int,
    notes: list[str],
) -> dict[str, ScenePlan]:
    """Scene key -> the images it holds, in key order (scene folders by id, then group / image)."""
    plans: dict[str, ScenePlan] = {}
    if layout.is_pbr:
        notes.append(f"{layout.folder}: objects are re-dropped every 25 images, so one Scene per image")
    single = []
    for sid, ims in selected.items():
        if layout.is_pbr or not all(index[sid][im] for im in ims):
            if not layout.is_pbr:
                single.append(sid)
            for im in ims:
                plans[f"{sid}/i{im:06d}"] = ScenePlan(sid, f"i{im:06d}", (im,), multi_view=False)
            continue
        for k, group in enumerate(group_views(ims, n_views, seed, scene_folder_to_int(sid))):
            plans[f"{sid}/g{k:02d}"] = ScenePlan(sid, f"g{k:02d}", tuple(group), multi_view=True)
    if single:
        notes.append(
            f"scenes {', '.join(single)}: an image lacks cam_R_w2c/cam_t_w2c, so multi-view is impossible:"
            " each image is its own Scene (camera frame = world frame)"
        )
    n_multi = sum(p.multi_view for p in plans.values())
    if n_multi:
        notes.append(
            f"multi-view groups: n_views={n_views}; per scene the selected images sorted by id, permuted by"
            f" numpy default_rng([seed={seed}, scene_id]) and cut into consecutive groups (the last may be"
            f" smaller): {n_multi} groups"
        )
    return plans


@dataclass(frozen=True)
class _CameraFile:
    """The split's root camera file (``camera_primesense.json``): image size and default depth scale."""

    name: str
    width: int
    height: int
    depth_scale: float | None


def _read_camera_file(root: Path, layout: SplitLayout) -> _CameraFile | None:
    if layout.camera_file is None or not (root / layout.camera_file).is_file():
        return None
    path = root / layout.camera_file
    cam = load_json(path)
    require_keys(cam, ("width", "height"), path, "camera")
    depth_scale = None
    if "depth_scale" in cam:
        depth_scale = as_number(cam["depth_scale"], path, "depth_scale")
        if depth_scale <= 0:
            raise DatasetError(f"expected a positive depth_scale, got {depth_scale}", file=path, field="depth_scale")
    width, height = as_int(cam["width"], path, "width"), as_int(cam["height"], path, "height")
    if width <= 0 or height <= 0:
        raise DatasetError(f"expected a positive image size, got {width}x{height}", file=path, field="width/height")
    return _CameraFile(layout.camera_file, width, height, depth_scale)


def _image_size(
    split_dir: Path,
    layout: SplitLayout,
    camera: _CameraFile | None,
    index: dict[str, dict[int, bool]],
    notes: list[str],
) -> tuple[tuple[int, int], bool]:
    """``(width, height)`` of the split's images and whether depth images exist.

    The size is voted by a few images (:func:`bop_cender.data.split_size.vote_image_size`): the declared
    size (camera file, else the layout's constant) wherever one sampled image agrees with it, so that a
    single wrong-sized image is the one ``info`` reports; else the images' own size, with a DatasetWarning.
    """
    declared, source = None, None
    if camera is not None:
        declared, source = (camera.width, camera.height), camera.name
    elif layout.image_size is not None:
        declared, source = tuple(layout.image_size), f"the {layout.folder} constant"
    first_dir = split_dir / next(iter(index))
    has_depth = (first_dir / "depth").is_dir() and any((first_dir / "depth").iterdir())
    voted = vote_image_size(_sample_images(split_dir, index), declared)
    if voted is None:
        if declared is None:
            raise DatasetError(
                "cannot tell the image size: no camera file with width/height and no image", file=first_dir
            )
        notes.append(f"image size {declared[0]}x{declared[1]} from {source}")
        return declared, has_depth
    actual = voted.size
    if declared is not None and declared != actual:
        warnings.warn(
            f"{source} says {declared[0]}x{declared[1]} but {voted.agreeing[0]} is {actual[0]}x{actual[1]}"
            f" (as {len(voted.agreeing)} of {len(voted.sampled)} sampled images are): using the images' size",
            DatasetWarning,
            stacklevel=3,
        )
        source = None
    checked = f"checked on {len(voted.agreeing)} of {len(voted.sampled)} sampled images"
    notes.append(f"image size {actual[0]}x{actual[1]}" + (f" ({source}, {checked})" if source else ""))
    return actual, has_depth


def _sample_images(split_dir: Path, index: dict[str, dict[int, bool]]) -> list[Path]:
    """The colour and depth images of the first views of the first scenes (existing or not)."""
    paths = []
    for scene_folder in list(index)[:SAMPLE_SCENES]:
        scene_dir = split_dir / scene_folder
        for im_id in sorted(index[scene_folder])[:SAMPLE_VIEWS_PER_SCENE]:
            for sub in (*RGB_FOLDERS, "depth"):
                paths.extend(scene_dir / sub / f"{im_id:06d}{ext}" for ext in IMAGE_SUFFIXES)
    return paths
