"""Per-scene done markers: what lets ``bop-cender synth`` tell a finished scene folder from a broken one.

A scene folder is written into a hidden sibling and renamed when complete, so an interrupted writer leaves
no folder. But a folder that exists is not proof of a complete scene: one restored from a partial copy,
a file truncated by a full disk or cut by hand, a folder of an older run. A resume that trusted the
folder would keep the damage and call the dataset complete. So when a folder is in place, its marker is
written (atomically, last): every file of the scene (and its contact sheet) with its size in bytes. A
scene is done only if its marker exists and every file it lists has that size; otherwise it is
regenerated. Checking sizes costs one ``stat`` per file, nothing against rendering a scene; a file
altered in place without a change of size is not detected (a hash would read every byte of the dataset
on every resume).

The markers live at the dataset root, in ``.bop_cender_synth/done/<split folder>/<scene folder>.json``,
beside the record (:mod:`bop_cender.synth.record`) and outside the real layout: the loaders never see them.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

from bop_cender.data.bop_io import save_json

#: The folder of the done markers, at the dataset root.
DONE_DIR = Path(".bop_cender_synth") / "done"


def marker_path(scene_dir: Path) -> Path:
    """The marker of ``ROOT/<split folder>/<scene folder>`` (both layouts put scenes two levels down)."""
    scene_dir = Path(scene_dir)
    return scene_dir.parent.parent / DONE_DIR / scene_dir.parent.name / f"{scene_dir.name}.json"


def marker_files(scene_dir: Path) -> dict[str, int] | None:
    """The files the marker of ``scene_dir`` lists (paths relative to the dataset root) with their sizes; None where
    there is no marker, or one that cannot be read (it proves nothing)."""
    try:
        files = json.loads(marker_path(scene_dir).read_text(encoding="utf-8"))["files"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return files if isinstance(files, dict) and files else None


def scene_done(scene_dir: Path) -> bool:
    """Whether the scene folder is complete: its marker lists files that all exist with their recorded size."""
    scene_dir = Path(scene_dir)
    files = marker_files(scene_dir) if scene_dir.is_dir() else None
    if files is None:
        return False
    root = scene_dir.parent.parent
    for rel, size in files.items():
        try:
            if (root / rel).stat().st_size != size:
                return False
        except OSError:
            return False
    return True


def write_marker(scene_dir: Path, extra: Iterable[Path] = ()) -> None:
    """Record every file under ``scene_dir`` and the ``extra`` files that exist (the contact sheet), with sizes."""
    scene_dir = Path(scene_dir)
    root = scene_dir.parent.parent
    paths = [p for p in sorted(scene_dir.rglob("*")) if p.is_file()]
    paths += [Path(p) for p in extra if Path(p).is_file()]
    files = {p.relative_to(root).as_posix(): p.stat().st_size for p in paths}
    save_json(marker_path(scene_dir), {"files": files})


def forget(scene_dir: Path) -> None:
    """Remove the marker of ``scene_dir``, if any (before the scene is written again)."""
    marker_path(scene_dir).unlink(missing_ok=True)
