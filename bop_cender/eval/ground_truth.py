"""Per-image ground truth for scoring, gathered once from a :class:`Dataset`.

BOP evaluates image by image: each target image has its intrinsics, its test depth and the list of
GT instances of its ``scene_gt.json`` (``gt_id`` = index in that list). The Dataset holds scenes of
static objects (``T_world_model``) seen by several views; this module turns them back into images.
It opens no file: everything comes from the loaded Dataset.

Which pose a GT instance has in an image: the pose STORED in that image's ``scene_gt.json`` entry, as
the loader read it (:attr:`~bop_cender.data.types.GtObject.T_cam_model`). That is what the official
toolkit compares against. ``T_cam_world @ T_world_model`` differs from it by the files' rounding
(T-LESS: R to 6 decimals, t to 0.01 mm), enough to change errors in their last digits; the composition
is the fallback for scenes held only in memory, and :attr:`GroundTruth.pose_source` says which was used.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bop_cender.data.scene_ids import int_to_scene_folder, is_suffixed, scene_folder_to_int
from bop_cender.data.types import Dataset, Scene
from bop_cender.errors import DatasetError
from bop_cender.progress import progress_bar

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
        dataset: the split they come from (to recognise images that exist on disk but were not selected:
            the toolkit ignores estimates for those).
        suffixed: whether scene folders carry a DIMO variant suffix (``000123_17``).
    """

    images: dict[tuple[int, int], ImageGt]
    pose_source: str
    dataset: Dataset | None = field(default=None, repr=False)
    suffixed: bool = False

    def __iter__(self) -> Iterator[ImageGt]:
        return iter(self.images.values())

    def __len__(self) -> int:
        return len(self.images)

    def image_on_disk(self, scene_int: int, im_id: int) -> bool:
        """Whether the split has this image on disk (selected or not)."""
        if (scene_int, im_id) in self.images:
            return True
        folder = self._folder(scene_int)
        ids = None if folder is None or self.dataset is None else self.dataset.image_ids_on_disk(folder)
        return ids is not None and im_id in ids

    def scene_on_disk(self, scene_int: int) -> bool:
        """Whether the split has a folder for this scene (selected or not)."""
        if any(s == scene_int for s, _ in self.images):
            return True
        folder = self._folder(scene_int)
        return folder is not None and self.dataset is not None and self.dataset.scene_on_disk(folder)

    def _folder(self, scene_int: int) -> str | None:
        try:
            return int_to_scene_folder(scene_int, self.suffixed)
        except ValueError:
            return None


def collect_ground_truth(dataset: Dataset, progress: bool = True, scenes: Sequence[Scene] | None = None) -> GroundTruth:
    """Load every scene of ``dataset`` (or take ``scenes``, some of its loaded scenes) and list its images with
    their GT instances.

    Raises:
        DatasetError: an image appears in two scenes.
    """
    images: dict[tuple[int, int], ImageGt] = {}
    sources: set[str] = set()
    suffixed = False
    scenes = progress_bar(
        dataset.scenes() if scenes is None else scenes,
        total=len(dataset) if scenes is None else len(scenes),
        desc="ground truth",
        unit="scene",
        disable=not progress,
        leave=False,
    )
    for scene in scenes:
        suffixed |= is_suffixed(scene.scene_id)
        scene_dir = None if dataset.split_dir is None else dataset.split_dir / scene.scene_id
        for image, stored in _scene_images(scene, scene_dir):
            if stored is not None:
                sources.add(POSES_STORED if stored else POSES_COMPOSED)
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
    return GroundTruth(images, source, dataset, suffixed)


def _scene_images(scene: Scene, scene_dir: Path | None) -> Iterator[tuple[ImageGt, bool | None]]:
    """Each evaluated view as an ImageGt (a multi-sensor scene's other sensors are no BOP images), and whether all its
    poses were stored (None: no GT instance)."""
    scene_int = scene_folder_to_int(scene.scene_id)
    for view in scene.evaluated_views:
        im = view.im_id
        instances = []
        stored: bool | None = None
        for obj in scene.gt:
            if im not in obj.gt_ids:
                continue
            T = obj.T_cam_model.get(im)
            stored = (T is not None) if stored is None else stored and T is not None
            if T is None:
                T = view.T_cam_world @ obj.T_world_model
            instances.append(GtPose(int(obj.gt_ids[im]), obj.obj_id, T, obj.visib_fract.get(im)))
        instances.sort(key=lambda g: g.gt_id)
        image = ImageGt(
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
        yield image, stored
