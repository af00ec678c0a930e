"""A human-readable summary of a dataset split: what ``bop-cender info`` prints."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from bop_cender.data.types import Dataset, Sensor
from bop_cender.errors import BopCenderError
from bop_cender.progress import progress_bar


@dataclass
class DatasetSummary:
    """Counts gathered by loading every scene of a split once (which also runs every consistency check)."""

    scenes: int = 0
    views: int = 0
    gt_instances: int = 0
    target_instances: int = 0
    views_per_scene: Counter = field(default_factory=Counter)
    objects_per_id: Counter = field(default_factory=Counter)
    image_sizes: Counter = field(default_factory=Counter)
    loaded: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)


SHOWN_KEYS = 5
"""Scene keys named in a problem line that several scenes share (a T-LESS scene has about 100 view groups)."""


def summarise(dataset: Dataset, progress: bool = True, keep_going: bool = False) -> DatasetSummary:
    """Load every scene (lazily, with a progress bar on stderr) and count what is there.

    Args:
        keep_going: a scene that fails to load is listed in ``problems`` (one line) and left out of the counts,
            so that every broken scene is reported at once; else its error is raised.
    """
    s = DatasetSummary()
    keys = dataset.scene_keys
    failed: dict[str, list[str]] = {}  # one line per error: a scene's view groups share its broken file
    bar = progress_bar(keys, desc="loading scenes", unit="scene", disable=not progress or len(keys) < 20, leave=False)
    for key in bar:
        try:
            scene = dataset.scene(key)
        except BopCenderError as e:
            if not keep_going:
                raise
            failed.setdefault(e.format(), []).append(key)
            continue
        s.loaded.append(key)
        s.scenes += 1
        s.views += len(scene.views)
        s.views_per_scene[len(scene.views)] += 1
        for v in scene.views:
            s.image_sizes[(v.width, v.height)] += 1
        for g in scene.gt:
            s.gt_instances += 1
            s.objects_per_id[g.obj_id] += 1
            model = dataset.models.get(g.obj_id)
            if model is not None and model.is_target:
                s.target_instances += 1
    for message, where in failed.items():
        if len(where) > 1:
            more = f" and {len(where) - SHOWN_KEYS} more" if len(where) > SHOWN_KEYS else ""
            message += f" (scenes {', '.join(where[:SHOWN_KEYS])}{more}: the same error)"
        s.problems.append(message)
    return s


def _ids(ids: list[int]) -> str:
    return ", ".join(str(i) for i in ids) if ids else "none"


def _sensor(dataset: Dataset, sensor: Sensor) -> str:
    """``xyz 1440x1080 gray, depth (evaluated: gray)``."""
    evaluated = f" (evaluated: {sensor.intensity})" if sensor.name == dataset.eval_sensor else ""
    return f"{sensor.name} {sensor.image_size[0]}x{sensor.image_size[1]} {', '.join(sensor.modalities)}{evaluated}"


def describe(dataset: Dataset, progress: bool = True, summary: DatasetSummary | None = None) -> str:
    """Multi-line text: scenes, views, objects, symmetric models, a multi-sensor split's sensors (size, modalities,
    which one is evaluated), the selection and why, residuals.

    Args:
        summary: the split's counts when already gathered (:func:`summarise`); else every scene is loaded here.
    """
    s = summary if summary is not None else summarise(dataset, progress=progress)
    models = dataset.models
    targets = [i for i, m in models.items() if m.is_target]
    occluders = [i for i, m in models.items() if not m.is_target]
    sym_cont = [i for i in targets if models[i].symmetries_continuous]
    sym_disc = [i for i in targets if models[i].symmetries_discrete and not models[i].symmetries_continuous]
    sizes = ", ".join(f"{w}x{h} ({n} views)" for (w, h), n in sorted(s.image_sizes.items())) or "-"
    vps = ", ".join(f"{n} scenes with {v}" for v, n in sorted(s.views_per_scene.items())) or "-"
    lines = [
        f"dataset   {dataset.name}, split {dataset.split}",
        f"root      {dataset.root}",
        f"models    {len(targets)} targets (ids {_ids(targets)}); {len(occluders)} occluders (ids {_ids(occluders)})",
        f"symmetric continuous: {_ids(sym_cont)}; discrete only: {_ids(sym_disc)}",
        f"scenes    {s.scenes}",
        f"views     {s.views} ({vps}); image size {sizes}; depth images: {'yes' if dataset.has_depth else 'no'}",
        f"objects   {s.gt_instances} GT instances ({s.target_instances} of target objects); per object id: "
        + (", ".join(f"{i}: {n}" for i, n in sorted(s.objects_per_id.items())) or "none"),
    ]
    if dataset.sensors:
        lines.insert(5, "sensors   " + "; ".join(_sensor(dataset, sensor) for sensor in dataset.sensors))
    if dataset.eval_models and any(m.path != models.get(i, m).path for i, m in dataset.eval_models.items()):
        lines.append(f"eval      {len(dataset.eval_models)} evaluation models")
    if dataset.selection:
        lines.append("selection")
        lines += [f"  - {note}" for note in dataset.selection]
    if dataset.residuals:
        parts = [f"{k} {v:.4g}" for k, v in sorted(dataset.residuals.items())]
        lines.append("pose consistency (largest residuals between files): " + ", ".join(parts))
    return "\n".join(lines)
