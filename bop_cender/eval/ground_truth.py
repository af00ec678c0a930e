"""Per-image ground truth for scoring, gathered once from a :class:`Dataset`.

BOP evaluates image by image: each target image has its intrinsics, its test depth and the list of
GT instances of its ``scene_gt.json`` (``gt_id`` = index in that list). The Dataset holds scenes of
static objects (``T_world_model``) seen by several views; this module turns them back into images.

Which pose a GT instance has in an image: the pose STORED in that image's ``scene_gt.json`` entry,
read here from the scene folder, when the file is there (every BOP and DIMO scene folder has one).
That is what the official toolkit compares against. ``T_cam_world @ T_world_model`` differs from it
by the files' rounding (T-LESS: R to 6 decimals, t to 0.01 mm), enough to change errors in their
last digits; the composition is the fallback for scenes without a ``scene_gt.json`` (synthetic
data held only in memory), and :attr:`GroundTruth.pose_source` says which was used.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from bop_cender.data.bop_io import load_json
from bop_cender.data.layout import SCENE_CAMERA, SCENE_GT
from bop_cender.data.scene_ids import int_to_scene_folder, is_suffixed, scene_folder_to_int
from bop_cender.data.types import Dataset, Scene
from bop_cender.errors import DatasetError
from bop_cender.geometry.poses import pose_from_bop

POSES_STORED = "scene_gt.json (per-image poses as stored, as the toolkit reads them)"
POSES_COMPOSED = "T_cam_world @ T_world_model (no scene_gt.json)"


@dataclass(frozen=True, eq=False)
class GtPose:
    """One GT instance in one image.

    Attributes:
        gt_id: index in the image's ``scene_gt.json`` list.
        obj_id: object id.
        T_cam_model: ``(4, 4)`` float64 model-to-camera pose, mm.
        visib_fract: visible fraction from ``scene_gt_info.json``; None when the dataset has none.
    """

    gt_id: int
    obj_id: int
    T_cam_model: np.ndarray
    visib_fract: float | None


@dataclass(frozen=True, eq=False)
class ImageGt:
    """One image of the split as the scorer sees it.

    Attributes:
        scene_id: scene folder name (``000001``, ``000123_17``); scene_int: its BOP int id.
        K: ``(3, 3)`` intrinsics. width, height: image size (px).
        depth_path: test depth PNG, None without depth; depth_scale: mm per depth unit.
        instances: GT instances sorted by gt_id.
        scene_key: key of the Scene the image came from.
        scene_dir: the scene folder on disk (None for in-memory scenes).
    """

    scene_id: str
    scene_int: int
    im_id: int
    K: np.ndarray
    width: int
    height: int
    depth_path: Path | None
    depth_scale: float | None
    instances: tuple[GtPose, ...]
    scene_key: str
    scene_dir: Path | None = None

    @property
    def key(self) -> tuple[int, int]:
        return (self.scene_int, self.im_id)


@dataclass
class GroundTruth:
    """Every selected image of a dataset split, keyed by ``(scene_int, im_id)``, in dataset order.

    Attributes:
        images: the selected images.
        pose_source: where GT poses came from (:data:`POSES_STORED` or :data:`POSES_COMPOSED`).
        split_dirs: folders holding the split's scene folders (to recognise images that exist on
            disk but were not selected: the toolkit ignores estimates for those).
        suffixed: whether scene folders carry a DIMO variant suffix (``000123_17``).
    """

    images: dict[tuple[int, int], ImageGt]
    pose_source: str
    split_dirs: tuple[Path, ...] = ()
    suffixed: bool = False
    _camera_ids: dict[Path, frozenset[int] | None] = field(default_factory=dict, repr=False)

    def __iter__(self) -> Iterator[ImageGt]:
        return iter(self.images.values())

    def __len__(self) -> int:
        return len(self.images)

    def image_on_disk(self, scene_int: int, im_id: int) -> bool:
        """Whether the split has this image on disk (selected or not), from its ``scene_camera.json``."""
        if (scene_int, im_id) in self.images:
            return True
        try:
            folder = int_to_scene_folder(scene_int, self.suffixed)
        except ValueError:
            return False
        for split_dir in self.split_dirs:
            ids = self._image_ids(split_dir / folder / SCENE_CAMERA)
            if ids is not None and im_id in ids:
                return True
        return False

    def scene_on_disk(self, scene_int: int) -> bool:
        """Whether the split has a folder for this scene (selected or not)."""
        if any(s == scene_int for s, _ in self.images):
            return True
        try:
            folder = int_to_scene_folder(scene_int, self.suffixed)
        except ValueError:
            return False
        return any((d / folder / SCENE_CAMERA).is_file() for d in self.split_dirs)

    def _image_ids(self, path: Path) -> frozenset[int] | None:
        if path not in self._camera_ids:
            ids = None
            if path.is_file():
                content = load_json(path, keys_to_int=True)
                ids = frozenset(k for k in content if isinstance(k, int)) if isinstance(content, dict) else None
            self._camera_ids[path] = ids
        return self._camera_ids[path]


def collect_ground_truth(dataset: Dataset, progress: bool = True) -> GroundTruth:
    """Load every scene of ``dataset`` and list its images with their GT instances.

    Raises:
        DatasetError: an image appears in two scenes, or a stored ``scene_gt.json`` entry disagrees
            with the loader's association (another obj_id at that gt_id).
    """
    images: dict[tuple[int, int], ImageGt] = {}
    stored_cache: dict[Path, dict[int, list[dict]] | None] = {}
    sources: set[str] = set()
    split_dirs: dict[Path, None] = {}
    suffixed = False
    scenes = tqdm(
        dataset.scenes(), total=len(dataset), desc="ground truth", unit="scene", disable=not progress, leave=False
    )
    for scene in scenes:
        suffixed |= is_suffixed(scene.scene_id)
        scene_dir = _scene_dir(scene)
        stored = None
        if scene_dir is not None:
            split_dirs[scene_dir.parent] = None
            if scene_dir not in stored_cache:
                stored_cache.clear()  # consecutive scenes share folders (view groups): keep the last one
                path = scene_dir / SCENE_GT
                stored_cache[scene_dir] = load_json(path, keys_to_int=True) if path.is_file() else None
            stored = stored_cache[scene_dir]
        sources.add(POSES_STORED if stored is not None else POSES_COMPOSED)
        for image in _scene_images(scene, stored, scene_dir):
            if image.key in images:
                raise DatasetError(
                    f"image {image.im_id} of scene {image.scene_id} is in two scenes"
                    f" ({images[image.key].scene_key} and {image.scene_key}); expected each image once",
                    file=dataset.root,
                )
            images[image.key] = image
    source = POSES_STORED if sources == {POSES_STORED} else POSES_COMPOSED if sources else POSES_STORED
    if len(sources) > 1:
        source = f"{POSES_STORED}; {POSES_COMPOSED} for some scenes"
    return GroundTruth(images, source, tuple(split_dirs), suffixed)


def _scene_dir(scene: Scene) -> Path | None:
    """The scene's folder (where its ``scene_camera.json`` is), None for in-memory scenes."""
    source = scene.views[0].source if scene.views else None
    if not source:
        return None
    path = Path(source)
    return path.parent if path.name == SCENE_CAMERA else None


def _scene_images(scene: Scene, stored: dict[int, list[dict]] | None, scene_dir: Path | None) -> Iterator[ImageGt]:
    scene_int = scene_folder_to_int(scene.scene_id)
    for view in scene.views:
        im = view.im_id
        instances = []
        for obj in scene.gt:
            if im not in obj.gt_ids:
                continue
            gt_id = int(obj.gt_ids[im])
            T = view.T_cam_world @ obj.T_world_model
            if stored is not None:
                T = _stored_pose(stored, im, gt_id, obj.obj_id, scene_dir)
            instances.append(GtPose(gt_id, obj.obj_id, T, obj.visib_fract.get(im)))
        instances.sort(key=lambda g: g.gt_id)
        yield ImageGt(
            scene_id=scene.scene_id,
            scene_int=scene_int,
            im_id=im,
            K=view.K,
            width=int(view.width),
            height=int(view.height),
            depth_path=view.depth_path,
            depth_scale=view.depth_scale,
            instances=tuple(instances),
            scene_key=scene.key,
            scene_dir=scene_dir,
        )


def _stored_pose(stored: dict[int, list[dict]], im: int, gt_id: int, obj_id: int, scene_dir: Path | None) -> np.ndarray:
    """``(4, 4)`` pose of ``scene_gt.json[im][gt_id]``, float64 exactly as stored."""
    path = None if scene_dir is None else scene_dir / SCENE_GT
    entries = stored.get(im)
    if not isinstance(entries, list) or gt_id >= len(entries):
        raise DatasetError(f"no entry {gt_id} for image {im}", file=path, field=f"{im}[{gt_id}]")
    entry = entries[gt_id]
    if int(entry.get("obj_id", -1)) != obj_id:
        raise DatasetError(
            f"obj_id {entry.get('obj_id')!r} where the loaded scene has obj {obj_id}", file=path, field=f"{im}[{gt_id}]"
        )
    return pose_from_bop(entry["cam_R_m2c"], entry["cam_t_m2c"])


def split_folder(gt: GroundTruth, dataset: Dataset) -> str:
    """The split folder the images come from (``test_primesense``, ``test_kinect``), which names the split type
    the toolkit's constants depend on; the split name where there is no BOP folder (DIMO)."""
    first = next(iter(gt), None)
    if dataset.name != "dimo" and first is not None and first.scene_dir is not None:
        return first.scene_dir.parent.name
    return dataset.split
