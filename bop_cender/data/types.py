"""The dataclasses that flow between stages: cameras, models, GT objects, scenes, datasets.

Everything here is in millimetres and float64, and poses are named by their frames
(``T_cam_world`` maps world points into the camera frame). Constructors validate shapes,
finiteness and rotations, so a bad value fails where it enters, naming its source.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bop_cender.data.layout import SCENE_CAMERA
from bop_cender.errors import DatasetError
from bop_cender.geometry.rotations import orthonormality_error
from bop_cender.geometry.symmetry import (
    BOP19_MAX_SYM_DISC_STEP,
    ContinuousSymmetry,
    symmetry_transforms,
)

if TYPE_CHECKING:
    import trimesh

    from bop_cender.data.targets_file import Target

#: A rotation whose ``R R^T - I`` has an entry above this is not accepted (BOP files are rounded
#: to ~6 digits, so real rotations sit around 1e-6).
ROTATION_TOLERANCE = 1e-2


def check_matrix(value: Any, shape: tuple[int, ...], what: str, source: str | None = None) -> np.ndarray:
    """Return ``value`` as a finite float64 array of ``shape`` or raise a DatasetError naming it (a JSON
    ``true`` / ``false`` is not a number, though NumPy would read it as 1 / 0)."""
    try:
        if has_bool(value):
            raise TypeError("a bool is not a number")
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise DatasetError(f"expected numbers of shape {shape}, got {value!r:.80}", file=source, field=what) from None
    if arr.shape != shape:
        raise DatasetError(f"expected shape {shape}, got {arr.shape}", file=source, field=what)
    if not np.all(np.isfinite(arr)):
        raise DatasetError("expected finite numbers, found NaN or inf", file=source, field=what)
    return arr


def has_bool(value: Any) -> bool:
    """Whether a JSON value (nested lists) holds a bool, or is a bool array: not numbers, though NumPy reads them so."""
    if isinstance(value, bool | np.bool_):
        return True
    if isinstance(value, np.ndarray):
        return value.dtype == np.bool_
    return isinstance(value, list | tuple) and any(has_bool(v) for v in value)


def check_pose(T: Any, what: str, source: str | None = None, tol: float = ROTATION_TOLERANCE) -> np.ndarray:
    """Validate a 4x4 rigid transform: finite, last row (0, 0, 0, 1), R orthonormal with det +1."""
    T = check_matrix(T, (4, 4), what, source)
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise DatasetError("expected last row (0, 0, 0, 1)", file=source, field=what)
    R = T[:3, :3]
    err, det = float(orthonormality_error(R)), float(np.linalg.det(R))
    if err > tol or det < 0:
        raise DatasetError(
            f"rotation is not orthonormal (max |R R^T - I| = {err:.3g}, det = {det:.4f};"
            f" expected <= {tol:g} and det +1)",
            file=source,
            field=what,
        )
    return T


def check_intrinsics(K: Any, what: str, source: str | None = None) -> np.ndarray:
    """Validate a pinhole ``K (3, 3)``: positive focal lengths, last row (0, 0, 1)."""
    K = check_matrix(K, (3, 3), what, source)
    if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0.0, 0.0, 1.0]) or K[1, 0] != 0:
        raise DatasetError("expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0", file=source, field=what)
    return K


@dataclass(frozen=True, eq=False)
class CameraView:
    """One calibrated image of a scene.

    Attributes:
        im_id: BOP image id.
        K: ``(3, 3)`` pinhole intrinsics (pixel convention: pixel (u, v) centre at (u+0.5, v+0.5)).
        T_cam_world: ``(4, 4)`` world-to-camera transform, mm.
        width, height: image size in pixels.
        rgb_path: colour image (None when the dataset has none for this view).
        depth_path: 16-bit depth PNG, if any; ``depth_mm = png * depth_scale``.
        depth_scale: mm per depth unit.
        mask_paths: full-silhouette masks per GT instance, in ``scene_gt`` order (gt_id).
        mask_visib_paths: visible-part masks per GT instance, in ``scene_gt`` order.
        info: extra per-image keys (DIMO ``scene_info``: viewpoint, carrier, ...; multi-sensor layouts: the
            sensor's ``modality`` of ``rgb_path``, the BOP ``bop_im_id`` and other modalities' ``images``).
        sensor: the sensor that took the image in a multi-sensor layout (``xyz``, ``cam1``); None elsewhere.
        evaluated: whether BOP evaluates this image: results rows are written and scored for it. False for the
            views of a multi-sensor layout's other sensors, whose ``im_id`` is then a view id unique in its scene
            (:func:`bop_cender.data.industrial_scene.view_id`), not a BOP image id.
    """

    im_id: int
    K: np.ndarray
    T_cam_world: np.ndarray
    width: int
    height: int
    rgb_path: Path | None = None
    depth_path: Path | None = None
    depth_scale: float | None = None
    mask_paths: tuple[Path, ...] = ()
    mask_visib_paths: tuple[Path, ...] = ()
    info: Mapping[str, Any] = field(default_factory=dict)
    source: str | None = None
    sensor: str | None = None
    evaluated: bool = True

    def __post_init__(self) -> None:
        what = f"image {self.im_id}" if self.sensor is None else f"{self.sensor} image {self.im_id}"
        object.__setattr__(self, "K", check_intrinsics(self.K, f"{what}: K", self.source))
        object.__setattr__(self, "T_cam_world", check_pose(self.T_cam_world, f"{what}: T_cam_world", self.source))
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise DatasetError(
                f"image size must be positive, got {self.width}x{self.height}", file=self.source, field=what
            )
        if self.depth_scale is not None and not (math.isfinite(self.depth_scale) and self.depth_scale > 0):
            raise DatasetError(
                f"depth_scale must be a positive number, got {self.depth_scale}", file=self.source, field=what
            )

    @property
    def T_world_cam(self) -> np.ndarray:
        """Camera-to-world ``(4, 4)``."""
        from bop_cender.geometry.poses import invert_pose

        return invert_pose(self.T_cam_world)


@dataclass(eq=False)
class ObjectModel:
    """A 3D model with its BOP ``models_info.json`` entry.

    Attributes:
        obj_id: BOP object id.
        path: PLY file (mm). The mesh loads on first access to :attr:`mesh`.
        diameter: max distance between two vertices, mm.
        bbox_min: ``(3,)`` min corner of the 3D bounding box, mm.
        bbox_size: ``(3,)`` size of the 3D bounding box, mm.
        symmetries_discrete: flattened row-major 4x4 matrices.
        symmetries_continuous: rotational symmetries (axis, offset).
        is_target: False for DIMO carriers/background (ids >= 100): occluders, never targets.
    """

    obj_id: int
    path: Path
    diameter: float
    bbox_min: np.ndarray
    bbox_size: np.ndarray
    symmetries_discrete: list[list[float]] = field(default_factory=list)
    symmetries_continuous: list[ContinuousSymmetry] = field(default_factory=list)
    is_target: bool = True
    source: str | None = None

    def __post_init__(self) -> None:
        what = f"obj {self.obj_id}"
        if not (math.isfinite(self.diameter) and self.diameter > 0):
            raise DatasetError(
                f"diameter must be a positive number, got {self.diameter}", file=self.source, field=f"{what}: diameter"
            )
        self.bbox_min = check_matrix(self.bbox_min, (3,), f"{what}: min_x/min_y/min_z", self.source)
        self.bbox_size = check_matrix(self.bbox_size, (3,), f"{what}: size_x/size_y/size_z", self.source)
        if not (self.bbox_size > 0).all():  # a negative or zero extent: the centre and the box are wrong
            raise DatasetError(
                f"bounding-box sizes must be positive, got {self.bbox_size.tolist()}",
                file=self.source,
                field=f"{what}: size_x/size_y/size_z",
            )

    @property
    def center(self) -> np.ndarray:
        """3D object centre ``(3,)`` in model coordinates: bounding-box centre (docs/design.md, "Frames and units")."""
        return self.bbox_min + self.bbox_size / 2.0

    @property
    def is_symmetric(self) -> bool:
        return bool(self.symmetries_discrete or self.symmetries_continuous)

    @cached_property
    def mesh(self) -> trimesh.Trimesh:
        """The triangle mesh (mm), loaded once, vertices kept exactly as in the file."""
        from bop_cender.data.bop_io import load_ply

        return load_ply(self.path)

    def symmetry_transforms(self, max_sym_disc_step: float = BOP19_MAX_SYM_DISC_STEP) -> tuple[np.ndarray, np.ndarray]:
        """BOP symmetry set ``R (S, 3, 3)``, ``t (S, 3)``, identity first; at BOP's step, made once per model (a
        continuous symmetry is hundreds of rotations, asked for by every pose search and every scored pair) and
        read-only."""
        if max_sym_disc_step == BOP19_MAX_SYM_DISC_STEP:
            return self._bop_symmetry_transforms
        return symmetry_transforms(self.symmetries_discrete, self.symmetries_continuous, max_sym_disc_step)

    @cached_property
    def _bop_symmetry_transforms(self) -> tuple[np.ndarray, np.ndarray]:
        R, t = symmetry_transforms(self.symmetries_discrete, self.symmetries_continuous, BOP19_MAX_SYM_DISC_STEP)
        R.setflags(write=False)
        t.setflags(write=False)
        return R, t


@dataclass(frozen=True, eq=False)
class GtObject:
    """One ground-truth object instance, static in the scene's world frame.

    Attributes:
        obj_id: BOP object id.
        T_world_model: ``(4, 4)`` model-to-world transform, mm.
        gt_ids: per image id, this instance's index in that image's ``scene_gt`` list.
        visib_fract: per image id, visible fraction from ``scene_gt_info.json`` when known.
        T_cam_model: per image id, the ``(4, 4)`` model-to-camera pose STORED in that image's ``scene_gt``
            entry, float64 exactly as read (empty for scenes held only in memory). Evaluation scores against
            these, as the toolkit does: ``T_cam_world @ T_world_model`` differs from them by the files'
            rounding (T-LESS: R to 6 decimals, t to 0.01 mm), enough to change errors in their last digits.
    """

    obj_id: int
    T_world_model: np.ndarray
    gt_ids: Mapping[int, int] = field(default_factory=dict)
    visib_fract: Mapping[int, float] = field(default_factory=dict)
    T_cam_model: Mapping[int, np.ndarray] = field(default_factory=dict)
    source: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "T_world_model", check_pose(self.T_world_model, f"obj {self.obj_id}: T_world_model", self.source)
        )


@dataclass(frozen=True, eq=False)
class Scene:
    """A set of calibrated views of one static arrangement of objects, and its ground truth.

    Attributes:
        dataset: dataset name (``dimo``, ``tless``, or a BOP dataset name).
        split: the user's split name (``real``, ``sim``, ``train``, ``test``, ``train_pbr``).
        scene_id: BOP scene folder name as a string (DIMO sim: ``000123_17``).
        views: the selected views.
        gt: ground-truth instances (may be empty for unannotated data).
        key_suffix: distinguishes several Scenes cut from one folder: ``g03`` for the fourth
            T-LESS view group, ``i000123`` for one train_pbr image; empty for a whole folder.
        info: free-form notes (e.g. DIMO carrier, composition).
    """

    dataset: str
    split: str
    scene_id: str
    views: tuple[CameraView, ...]
    gt: tuple[GtObject, ...] = ()
    key_suffix: str = ""
    info: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        ids = [v.im_id for v in self.views]
        if len(set(ids)) != len(ids):
            raise DatasetError(f"scene {self.scene_id}: duplicate image ids {sorted(ids)}")

    @property
    def key(self) -> str:
        """Unique name within the dataset split: ``scene_id``, or ``scene_id/suffix`` (see key_suffix)."""
        return f"{self.scene_id}/{self.key_suffix}" if self.key_suffix else self.scene_id

    @property
    def im_ids(self) -> list[int]:
        return [v.im_id for v in self.views]

    @property
    def evaluated_views(self) -> tuple[CameraView, ...]:
        """The views BOP evaluates (all but a multi-sensor layout's other sensors): results rows are theirs."""
        return tuple(v for v in self.views if v.evaluated)

    def view(self, im_id: int) -> CameraView:
        for v in self.views:
            if v.im_id == im_id:
                return v
        raise KeyError(im_id)


@dataclass(frozen=True)
class Sensor:
    """One sensor of a multi-sensor split (BOP-Industrial: IPD, XYZ-IBD, ITODD-MV).

    Attributes:
        name: as in its file names (``scene_camera_{name}.json``, ``gray_{name}/``).
        modalities: its image folders' modalities (``rgb``, ``gray``, ``depth``, ``aolp``, ``dolp``), in table order.
        image_size: ``(width, height)`` of its images, px.
    """

    name: str
    modalities: tuple[str, ...]
    image_size: tuple[int, int]

    @property
    def intensity(self) -> str | None:
        """The modality of its views' ``rgb_path``: ``rgb``, else ``gray``, else None."""
        return next((m for m in ("rgb", "gray") if m in self.modalities), None)


@dataclass(eq=False)
class Dataset:
    """A dataset split on disk: its models, its scene keys and lazily loaded scenes.

    Attributes:
        root: dataset root folder.
        name: dataset name as BOP writes it in result file names (``dimo``, ``tless``, ...).
        split: the user's split name.
        models: target and occluder models, by obj_id (``models/`` or ``models_cad/``).
        eval_models: models used by evaluation (``models_eval/``), by obj_id.
        scene_keys: keys of the scenes, in order (see :attr:`Scene.key`).
        selection: human-readable notes on what the split selected and why.
        residuals: largest pose-consistency residuals seen while loading (mm, rad).
        image_size: (width, height) of the split's images.
        has_depth: whether test depth images exist (VSD needs them).
        split_dir: the folder holding the split's scene folders (``test_primesense/``, DIMO ``real_jaigo/``);
            None for data held only in memory.
        sensors: a multi-sensor split's sensors, the evaluated one first; empty elsewhere.
        eval_sensor: the sensor whose images BOP evaluates (``image_size`` is its size); None elsewhere.
        scene_camera_name: the per-scene camera file that lists the split's BOP images (``scene_camera.json``;
            multi-sensor: ``scene_camera_{eval_sensor}.json``).
    """

    root: Path
    name: str
    split: str
    models: dict[int, ObjectModel]
    scene_keys: list[str]
    loader: Callable[[str], Scene]
    eval_models: dict[int, ObjectModel] = field(default_factory=dict)
    selection: list[str] = field(default_factory=list)
    residuals: dict[str, float] = field(default_factory=dict)
    image_size: tuple[int, int] | None = None
    has_depth: bool = False
    split_dir: Path | None = None
    sensors: tuple[Sensor, ...] = ()
    eval_sensor: str | None = None
    scene_camera_name: str = SCENE_CAMERA
    _cache: dict[str, Scene] = field(default_factory=dict, repr=False)
    _on_disk: dict[str, frozenset[int] | None] = field(default_factory=dict, repr=False)
    _files: dict[str, Any] = field(default_factory=dict, repr=False)

    def scene(self, key: str) -> Scene:
        """Load (once) and return the scene with this key."""
        if key not in self._cache:
            if key not in self._known_keys:
                raise DatasetError(f"unknown scene {key!r}; known: {', '.join(self.scene_keys[:10])}", file=self.root)
            self._cache[key] = self.loader(key)
        return self._cache[key]

    @functools.cached_property
    def _known_keys(self) -> frozenset[str]:
        """The scene keys as a set (a list lookup per scene made loading N scenes O(N^2))."""
        return frozenset(self.scene_keys)

    def scenes(self) -> Iterator[Scene]:
        """All scenes of the split in order, loaded lazily."""
        for key in self.scene_keys:
            yield self.scene(key)

    @property
    def split_folder(self) -> str:
        """The split folder's name (``test_primesense``: its suffix is the BOP split type); the split name without one."""
        return self.split_dir.name if self.split_dir is not None else self.split

    def bop19_targets(self) -> list[Target] | None:
        """The dataset's ``test_targets_bop19.json`` (at its root), read once; None without one.

        Raises:
            DatasetError: the file is malformed (every entry needs integer ids and ``inst_count`` >= 1).
        """
        if "targets" not in self._files:
            from bop_cender.data.layout import TARGETS_FILE
            from bop_cender.data.targets_file import read_targets

            path = self.root / TARGETS_FILE
            self._files["targets"] = read_targets(path) if path.is_file() else None
        return self._files["targets"]

    def scene_on_disk(self, scene_id: str) -> bool:
        """Whether the split has a folder for this scene id (selected or not)."""
        return self.split_dir is not None and (self.split_dir / scene_id / self.scene_camera_name).is_file()

    def image_ids_on_disk(self, scene_id: str) -> frozenset[int] | None:
        """Image ids of a scene folder of the split, selected or not (its ``scene_camera.json``); None without one."""
        if self.split_dir is None:
            return None
        if scene_id not in self._on_disk:
            from bop_cender.data.bop_io import load_json

            path = self.split_dir / scene_id / self.scene_camera_name
            ids = None
            if path.is_file():
                content = load_json(path, keys_to_int=True)
                ids = frozenset(k for k in content if isinstance(k, int)) if isinstance(content, dict) else None
            self._on_disk[scene_id] = ids
        return self._on_disk[scene_id]

    @property
    def target_obj_ids(self) -> list[int]:
        return sorted(i for i, m in self.models.items() if m.is_target)

    def __len__(self) -> int:
        return len(self.scene_keys)
