"""Per-scene shards: one small JSON file per finished scene, and what ``--resume`` keeps of them.

A scene's outcome is written into the run's work folder (``<out>.parts/``, beside the output) as soon as it is
known, atomically, so a run killed at any point leaves only whole shards. A shard carries the fingerprint of the
settings it was made with (:meth:`~bop_cender.runner.request.RunRequest.fingerprint`); ``--resume`` keeps those of
the same settings, of the right scene and of the dataset's target objects, and redoes the rest.
"""

from __future__ import annotations

import json
import re
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bop_cender.data.bop_io import atomic_path
from bop_cender.errors import BopCenderError
from bop_cender.estimates import ObjectEstimate, SceneEstimate

SHARD_FORMAT = "bop-cender-shard"


SHARD_VERSION = 1


@dataclass(frozen=True)
class SceneOutcome:
    """One scene's result as the runner keeps it (what a shard holds)."""

    scene_key: str
    estimate: SceneEstimate | None
    error: str | None = None


def work_dir(out: Path) -> Path:
    """The shard folder of an output CSV: ``<out>.parts`` beside it."""
    out = Path(out)
    return out.with_name(out.name + ".parts")


def shard_path(work: Path, scene_key: str) -> Path:
    """One shard per scene key (``/`` of a suffixed key becomes ``__``)."""
    return work / (re.sub(r"[^A-Za-z0-9_.-]", "__", scene_key) + ".json")


def write_shard(path: Path, outcome: SceneOutcome, fingerprint: str) -> None:
    """``outcome`` as a shard at ``path`` (atomically), with the ``fingerprint`` of the settings that made it; a failed
    scene's shard holds its error and no estimate."""
    est = outcome.estimate
    content: dict[str, Any] = {
        "format": SHARD_FORMAT,
        "version": SHARD_VERSION,
        "fingerprint": fingerprint,
        "scene_key": outcome.scene_key,
        "error": outcome.error,
    }
    if est is not None:
        content.update(
            scene_id=est.scene_id,
            time_s=est.time_s,
            timings=dict(est.timings),
            objects=[
                {
                    "obj_id": o.obj_id,
                    "score": o.score,
                    "T_world_model": np.asarray(o.T_world_model).tolist(),
                    "image_scores": {str(k): v for k, v in o.image_scores.items()},
                }
                for o in est.objects
            ],
        )
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(content, indent=1))


def read_shard(
    path: Path, fingerprint: str, scene_key: str | None = None, obj_ids: Collection[int] | None = None
) -> SceneOutcome | None:
    """A shard made with the same settings, or None (missing, other settings, unreadable, or of a scene that failed:
    it is redone). With ``scene_key``, a shard of another scene is None too; with ``obj_ids`` (the dataset's target
    objects), one that estimates another object (an edited or foreign shard wrote rows of a carrier or of an unknown
    id, or ended the run in a traceback)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("format") != SHARD_FORMAT or data.get("fingerprint") != fingerprint:
        return None
    if data.get("error") is not None:
        return None  # a failed scene is tried again (its input may have been mended since)
    try:
        objects = tuple(
            ObjectEstimate(
                o["obj_id"],
                np.array(o["T_world_model"]),
                o["score"],
                {int(k): v for k, v in o.get("image_scores", {}).items()},
            )
            for o in data["objects"]
        )
        est = SceneEstimate(data["scene_key"], data["scene_id"], objects, data["time_s"], data["timings"])
    except (KeyError, TypeError, ValueError, BopCenderError):
        return None
    if scene_key is not None and est.scene_key != scene_key:  # (its scene_id follows: SceneEstimate checks them)
        return None
    if obj_ids is not None and any(o.obj_id not in obj_ids for o in est.objects):
        return None
    return SceneOutcome(data["scene_key"], est)


def resumable_outcomes(
    work: Path, keys: list[str], fingerprint: str, obj_ids: Collection[int]
) -> dict[str, SceneOutcome]:
    """The outcomes ``--resume`` keeps, by scene key: the shards in ``work`` of scenes of ``keys`` that
    :func:`read_shard` accepts (same ``fingerprint``, their own scene, only objects of ``obj_ids``, no error)."""
    outcomes: dict[str, SceneOutcome] = {}
    for key in keys:
        shard = read_shard(shard_path(work, key), fingerprint, key, obj_ids)
        if shard is not None:
            outcomes[key] = shard
    return outcomes


def other_settings_shards(work: Path, keys: list[str], fingerprint: str) -> int:
    """How many shards in ``work`` of scenes of ``keys`` were made with another ``fingerprint`` (other settings,
    weights or data, or an older bop-cender): ``--resume`` redoes them, and a user who changed nothing on purpose
    should hear it. A failed scene's or a damaged shard is not counted (its scene is redone for that reason)."""
    count = 0
    for key in keys:
        try:
            data = json.loads(shard_path(work, key).read_text())
        except (OSError, ValueError):
            continue
        if isinstance(data, dict) and data.get("format") == SHARD_FORMAT and data.get("fingerprint") != fingerprint:
            count += 1
    return count


def make_dirs(folder: Path) -> list[Path]:
    """``mkdir -p folder``; returns the folders it created, outermost first (to remove them when nothing
    was written)."""
    created = [p for p in (*reversed(folder.parents), folder) if not p.exists()]
    folder.mkdir(parents=True, exist_ok=True)
    return created


def remove_empty(created: list[Path]) -> None:
    """Remove the folders :func:`make_dirs` created, innermost first, where they are still empty."""
    for folder in reversed(created):
        if not folder.exists():
            continue
        try:
            folder.rmdir()
        except OSError:  # not empty: another file landed there, and so in its parents
            return
