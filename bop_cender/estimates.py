"""The method's output: object poses in the scene's world frame, one ``SceneEstimate`` per scene.

A multi-view method estimates each object once per scene, in the world frame shared by all of the
scene's views (docs/design.md, "The data flow": ``SceneEstimate = [ObjectEstimate(obj_id, T_world_model, score)] +
timings``). Turning these into BOP's per-image camera-frame rows is :mod:`bop_cender.results.bop_csv`'
job, so nothing here knows about cameras or CSV files.

Poses are validated where they enter (finite, last row ``(0, 0, 0, 1)``, orthonormal ``R`` with
det +1, via :func:`bop_cender.data.types.check_pose`, which raises ``DatasetError`` naming the
object), so a broken estimate fails in the stage that produced it, not in the writer.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from bop_cender.data.scene_ids import scene_folder_to_int
from bop_cender.data.types import check_pose


@dataclass(frozen=True, eq=False)
class ObjectEstimate:
    """One estimated object instance.

    Attributes:
        obj_id: BOP object id (non-negative).
        T_world_model: ``(4, 4)`` float64 model-to-world transform, mm; stored read-only.
        score: confidence, higher is better (BOP ranks estimates per image by it); finite.
        image_scores: optional per-image factor in [0, 1] by image id (how well the object is seen
            there): its row in that image gets ``score * factor``, so that BOP's per-image top-n keeps the
            objects that image shows rather than ones hidden in it. Images not listed get ``score``.
    """

    obj_id: int
    T_world_model: np.ndarray
    score: float
    image_scores: Mapping[int, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if isinstance(self.obj_id, bool) or not isinstance(self.obj_id, int | np.integer) or self.obj_id < 0:
            raise ValueError(f"obj_id must be a non-negative int, got {self.obj_id!r}")
        object.__setattr__(self, "obj_id", int(self.obj_id))
        T = check_pose(self.T_world_model, f"obj {self.obj_id}: T_world_model").copy()
        T.setflags(write=False)
        object.__setattr__(self, "T_world_model", T)
        object.__setattr__(self, "score", _finite(self.score, f"obj {self.obj_id}: score"))
        factors = {}
        for im_id, value in dict(self.image_scores).items():
            x = _finite(value, f"obj {self.obj_id}: image_scores[{im_id!r}]")
            if not 0.0 <= x <= 1.0:
                raise ValueError(f"obj {self.obj_id}: image_scores[{im_id!r}]: expected a factor in [0, 1], got {x}")
            factors[int(im_id)] = x
        object.__setattr__(self, "image_scores", factors)

    def score_in(self, im_id: int) -> float:
        """The confidence of this estimate in image ``im_id``: ``score * image_scores[im_id]`` (or ``score``)."""
        return self.score * self.image_scores.get(im_id, 1.0)


@dataclass(frozen=True, eq=False)
class SceneEstimate:
    """All estimates of one scene and how long they took.

    Attributes:
        scene_key: the :attr:`bop_cender.data.types.Scene.key` this estimate belongs to
            (``scene_id`` or ``scene_id/suffix``).
        scene_id: BOP scene folder name (``000123`` or DIMO's ``000123_17``).
        objects: the estimated instances, in any order.
        time_s: wall-clock seconds for the whole scene (all views together); negative means
            unknown, as BOP's ``-1``.
        timings: optional per-stage seconds (``heatmaps``, ``centers``, ``poses``, ...).
    """

    scene_key: str
    scene_id: str
    objects: tuple[ObjectEstimate, ...]
    time_s: float
    timings: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        try:
            scene_folder_to_int(self.scene_id)
        except (TypeError, ValueError) as e:
            raise ValueError(f"scene estimate {self.scene_key!r}: {e}") from None
        if self.scene_key != self.scene_id and not self.scene_key.startswith(self.scene_id + "/"):
            raise ValueError(f"scene_key {self.scene_key!r} does not belong to scene_id {self.scene_id!r}")
        objects = tuple(self.objects)
        for o in objects:
            if not isinstance(o, ObjectEstimate):
                raise TypeError(f"scene {self.scene_key}: objects must be ObjectEstimate, got {type(o).__name__}")
        object.__setattr__(self, "objects", objects)
        object.__setattr__(self, "time_s", _finite(self.time_s, f"scene {self.scene_key}: time_s"))
        timings = {str(k): _finite(v, f"scene {self.scene_key}: timings[{k!r}]") for k, v in self.timings.items()}
        object.__setattr__(self, "timings", timings)


def _finite(value: object, what: str) -> float:
    """``value`` as a finite float, or a ValueError naming ``what``."""
    try:
        x = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"{what}: expected a number, got {value!r}") from None
    if not math.isfinite(x):
        raise ValueError(f"{what}: expected a finite number, got {x}")
    return x
