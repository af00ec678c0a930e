"""Small pieces shared by the DIMO and T-LESS writers: BOP JSON entries, atomic scene folders.

A scene folder is written into a hidden ``.NAME.partial-<pid>-<token>`` sibling of its own and renamed when
complete, then its done marker is written (:mod:`bop_cender.synth.done`, outside the real layout): that is
what makes ``bop-cender synth`` resumable. A scene whose marker is there and matches is skipped; any other
folder (interrupted, truncated, from an older run) is written again. The temporary folder is the writer's
own, so that two writers of one scene (a second ``synth`` started while the first one's workers still ran)
never write into, or delete, each other's: each renames a complete folder (before, they shared one
``.NAME.partial``, and the first to finish renamed a folder that the second had emptied: scene folders with
5 of 8 images, marked done). Leftovers of writers that are no longer running are removed.
"""

from __future__ import annotations

import errno
import os
import shutil
import uuid
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bop_cender.geometry.poses import invert_pose
from bop_cender.synth.done import forget, scene_done, write_marker
from bop_cender.synth.parts import Part
from bop_cender.synth.piles import PileGeometryCache, build_pile


def flat(a: np.ndarray) -> list[float]:
    """A float list (row-major) for JSON."""
    return [float(x) for x in np.asarray(a, dtype=np.float64).ravel()]


def camera_entry(K: np.ndarray, T_cam_world: np.ndarray, *, with_c2w: bool, **extra) -> dict:
    """A ``scene_camera.json`` entry: ``cam_K`` and the camera pose (w2c, and DIMO's c2w with ``with_c2w``)."""
    entry: dict = {"cam_K": flat(K)}
    if with_c2w:
        T_world_cam = invert_pose(T_cam_world)
        entry["cam_R_c2w"] = flat(T_world_cam[:3, :3])
        entry["cam_t_c2w"] = flat(T_world_cam[:3, 3])
    entry["cam_R_w2c"] = flat(T_cam_world[:3, :3])
    entry["cam_t_w2c"] = flat(T_cam_world[:3, 3])
    entry.update(extra)
    return entry


def gt_entry(obj_id: int, T_cam_model: np.ndarray) -> dict:
    """A ``scene_gt.json`` entry (model-to-camera)."""
    return {"obj_id": int(obj_id), "cam_R_m2c": flat(T_cam_model[:3, :3]), "cam_t_m2c": flat(T_cam_model[:3, 3])}


@contextmanager
def scene_folder(final_dir: Path, extra: Sequence[Path] = ()) -> Iterator[Path | None]:
    """Yield a temporary folder to write a scene into, renamed onto ``final_dir`` on success and then marked done.

    Yields None when ``final_dir`` is done (:func:`bop_cender.synth.done.scene_done`: skip it). A folder that
    is there but not done is replaced only once the new one is complete.

    Args:
        extra: files outside the folder written with it (its contact sheet), recorded in its marker too.
    """
    final_dir = Path(final_dir)
    if scene_done(final_dir):
        yield None
        return
    forget(final_dir)
    _remove_dead_partials(final_dir)
    tmp = final_dir.with_name(f".{final_dir.name}.partial-{os.getpid()}-{uuid.uuid4().hex[:8]}")
    tmp.mkdir(parents=True)
    asides: list[Path] = []
    try:
        yield tmp
        _rename_onto(tmp, final_dir, asides)
        write_marker(final_dir, extra)
    finally:
        for folder in (tmp, *asides):
            if folder.exists():
                shutil.rmtree(folder, ignore_errors=True)


def _rename_onto(tmp: Path, final_dir: Path, asides: list[Path], attempts: int = 5) -> None:
    """Rename the complete ``tmp`` onto ``final_dir``, moving a folder already there aside first (into ``asides``,
    removed by the caller). A rename cannot replace a non-empty folder, and another writer of the same scene may put
    its folder there between our move and our rename: then it is moved aside too and the rename tried again."""
    for attempt in range(attempts):
        if final_dir.exists():
            aside = tmp.with_name(f"{tmp.name}-old{attempt}")
            try:
                os.replace(final_dir, aside)
                asides.append(aside)
            except FileNotFoundError:  # another writer moved it first
                pass
        try:
            os.replace(tmp, final_dir)
            return
        except OSError as exc:
            if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST) or attempt == attempts - 1:
                raise


def _remove_dead_partials(final_dir: Path) -> None:
    """Remove ``final_dir``'s temporary siblings whose writer process is gone (an interrupted run's), and the
    ``.NAME.partial`` of versions before the per-writer names."""
    parent = final_dir.parent
    if not parent.is_dir():
        return
    for tmp in parent.glob(f".{final_dir.name}.partial*"):
        pid_text = tmp.name.removeprefix(f".{final_dir.name}.partial").lstrip("-").split("-")[0]
        if pid_text.isdigit() and _process_alive(int(pid_text)):
            continue
        shutil.rmtree(tmp, ignore_errors=True)


def _process_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: alive
        return True
    return True


@dataclass
class Pile:
    """A static arrangement: which model each instance is and where it is.

    Attributes:
        obj_ids: ``(M,)`` BOP object id per instance (the support, carrier or table, first).
        T_world_model: ``(M, 4, 4)`` poses (mm).
        gt_indices: indices of the instances written to scene_gt (DIMO: all; T-LESS: not the table).
    """

    obj_ids: list[int]
    T_world_model: np.ndarray
    gt_indices: list[int]


def make_pile(
    models: dict[int, Part],
    part_ids: list[int],
    support_id: int,
    support: Part,
    n_parts: int,
    composition: str | list[int],
    rng: np.random.Generator,
    support_in_gt: bool,
    cache: PileGeometryCache | None = None,
) -> Pile:
    """Drop ``n_parts`` of ``part_ids`` on the support (carrier or table) centred at the origin.

    ``cache``: the per-mesh drop data kept between piles (one per generating process).
    """
    meshes = [models[i].mesh for i in part_ids]
    placements = build_pile(meshes, support.mesh, np.eye(4), n_parts, rng, composition=composition, cache=cache)
    obj_ids = [support_id] + [part_ids[p.part_index] for p in placements]
    T = np.stack([np.eye(4)] + [p.T_world_model for p in placements])
    gt = list(range(len(obj_ids))) if support_in_gt else list(range(1, len(obj_ids)))
    return Pile(obj_ids=obj_ids, T_world_model=T, gt_indices=gt)
