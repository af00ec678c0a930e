"""Run the official toolkit's ``scripts/eval_bop24_pose.py`` itself on an export, and compare it with our BOP'24 scores.

``eval_bop24_pose.py`` starts ``eval_calc_errors.py`` and ``eval_calc_scores.py`` as child processes
(``subprocess.call``), which would not see the run-time registration of the exported dataset
(:func:`bop_toolkit_adapters.runtime.registered`). For the duration of :func:`evaluate_bop24` its
``subprocess.call`` runs each child in this process instead (``runpy``, the child's own ``sys.argv`` plus
``--datasets_path`` of the export, under the registration of its phase); everything else, the mAP aggregation
included, is the toolkit's own code, unchanged. Its ``scores_bop24.json`` is read back and compared key by key.

The export is the BOP'19 one (:func:`~bop_toolkit_adapters.export.export_for_toolkit`) plus a
``test_targets_bop24.json`` listing our target images in our order, with the object ids narrowed to the dataset's
target objects (DIMO's carriers are not detection targets on our side either).
"""

from __future__ import annotations

import contextlib
import logging
import subprocess
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from bop_cender.data.bop_io import load_json, save_json
from bop_cender.data.layout import TARGETS_FILE_BOP24
from bop_cender.eval.detection import BOP24_KEYS
from bop_cender.eval.detection_report import DetectionReport
from bop_cender.eval.ground_truth import collect_ground_truth
from bop_cender.eval.scoring_bop24 import target_images
from bop_toolkit_adapters.export import ToolkitExport, export_for_toolkit
from bop_toolkit_adapters.runtime import ToolkitRunError, _run, import_toolkit, registered

#: Two figures that differ by more than this are a disagreement (the issue's bar: equal to 1e-9).
TOLERANCE = 1e-9


@dataclass
class Bop24Crosscheck:
    """Our BOP'24 scores beside the toolkit's, and every difference.

    Attributes:
        ours, theirs: the seven keys each. object_aps: per error type and object, (ours, theirs) AP per threshold.
        differences: one line per key or per-object AP beyond :data:`TOLERANCE`.
    """

    ours: dict[str, float | None]
    theirs: dict[str, float | None]
    object_aps: dict[str, dict[int, tuple[list[float], list[float]]]] = field(default_factory=dict)
    differences: list[str] = field(default_factory=list)
    export: ToolkitExport | None = None

    @property
    def agrees(self) -> bool:
        return not self.differences


def export_bop24(dataset, results_csv: str | Path, out_dir: str | Path, progress: bool = True) -> ToolkitExport:
    """The BOP'19 export plus ``test_targets_bop24.json`` (our target images) and the target objects only."""
    export = export_for_toolkit(dataset, results_csv, out_dir, progress=progress)
    gt = collect_ground_truth(dataset, False)
    images = target_images(dataset, gt)
    save_json(
        export.datasets_path / export.dataset / TARGETS_FILE_BOP24,
        [{"im_id": im, "scene_id": scene} for scene, im in images.keys],
    )
    targets = set(dataset.target_obj_ids)
    return replace(export, obj_ids=tuple(o for o in export.obj_ids if o in targets))


@contextlib.contextmanager
def _children_in_process(export: ToolkitExport, quiet: bool) -> Iterator[None]:
    """``subprocess.call(["python", script, *args])`` of the toolkit's scripts, run here under the registration."""
    original = subprocess.call

    def call(cmd, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003 - subprocess.call's signature
        if not (isinstance(cmd, list) and len(cmd) >= 2 and str(cmd[1]).endswith(".py")):
            return original(cmd, *args, **kwargs)
        script = Path(cmd[1])
        phase = "scores" if script.name == "eval_calc_scores.py" else "errors"
        with registered(export, phase):
            _run(script, [*cmd[2:], f"--datasets_path={export.datasets_path}"], quiet)
        if quiet:  # the child's _run lifted the parent's silence on its way out
            logging.disable(logging.WARNING)
        return 0

    subprocess.call = call
    try:
        yield
    finally:
        subprocess.call = original


def evaluate_bop24(export: ToolkitExport, scripts: Path, quiet: bool = True) -> dict[str, Any]:
    """The toolkit's ``eval_bop24_pose.py`` on the export; its ``scores_bop24.json`` and per-object APs.

    Returns:
        ``{"scores": the seven keys, "object_aps": {error type: {obj_id: [AP per threshold]}}}``.

    Raises:
        ToolkitRunError: a script failed, or its output is not what this adapter reads.
    """
    args = [f"--result_filenames={export.result_filename}", f"--results_path={export.results_path}",
            f"--eval_path={export.eval_path}", f"--targets_filename={TARGETS_FILE_BOP24}", "--num_workers=1"]  # fmt: skip
    with _children_in_process(export, quiet):
        _run(scripts / "eval_bop24_pose.py", args, quiet)
    folder = export.eval_path / export.result_name
    path = folder / "scores_bop24.json"
    if not path.is_file():
        raise ToolkitRunError("eval_bop24_pose.py wrote no scores_bop24.json", file=path)
    scores = load_json(path)
    object_aps: dict[str, dict[int, list[float]]] = {}
    for name, sign in (("mssd", "mssd"), ("mssd_mm", "mssd"), ("mspd", "mspd")):
        # the mm thresholds' files sit beside the diameter ones (same error folder), told apart by their values
        files = sorted((folder / f"error={sign}_ntop=0").glob("scores_th=*.json"))
        picked = [f for f in files if _is_mm(f) == (name == "mssd_mm")] if sign == "mssd" else files
        per_obj: dict[int, list[float]] = {}
        for f in sorted(picked, key=_threshold_of):
            data = load_json(f)
            for obj, ap in data["scores"].items():
                if data["num_targets_per_object"][obj] > 0:
                    per_obj.setdefault(int(obj), []).append(float(ap))
        object_aps[name] = per_obj
    return {"scores": {k: scores.get(k) for k in BOP24_KEYS}, "object_aps": object_aps}


def _threshold_of(path: Path) -> float:
    return float(path.name.split("th=")[1].split("_")[0])


def _is_mm(path: Path) -> bool:
    return _threshold_of(path) >= 1.0  # 2 ... 20 mm; the diameter fractions are 0.05 ... 0.5


def compare_bop24(
    ours: DetectionReport, toolkit: dict[str, Any], export: ToolkitExport | None = None
) -> Bop24Crosscheck:
    """Every key and every per-object AP side by side; a difference above :data:`TOLERANCE` is listed."""
    theirs = toolkit["scores"]
    check = Bop24Crosscheck(dict(ours.scores), dict(theirs), export=export)
    for key in BOP24_KEYS:
        a, b = ours.scores.get(key), theirs.get(key)
        if (a is None) != (b is None) or (a is not None and abs(a - b) > TOLERANCE):
            check.differences.append(f"{key}: ours {a!r}, toolkit {b!r}")
    for name, s in ours.per_type.items():
        mine = {o: [c.ap for c in s.curves[o]] for o in s.objects}
        other = toolkit["object_aps"].get(name, {})
        check.object_aps[name] = {o: (mine.get(o, []), other.get(o, [])) for o in sorted(set(mine) | set(other))}
        for o, (a, b) in check.object_aps[name].items():
            if len(a) != len(b) or any(abs(x - y) > TOLERANCE for x, y in zip(a, b, strict=False)):
                check.differences.append(f"{name} AP of object {o}: ours {a}, toolkit {b}")
    return check


def crosscheck_bop24(
    results_csv: str | Path, ours: DetectionReport, dataset, out_dir: str | Path, toolkit_dir=None, quiet: bool = True,
    progress: bool = True,
) -> Bop24Crosscheck:  # fmt: skip
    """Export, run the toolkit's ``eval_bop24_pose.py``, compare with ``ours`` (the same file scored by us).

    Raises:
        ToolkitUnavailable: the toolkit cannot be imported. ToolkitRunError: it failed.
    """
    _, scripts = import_toolkit(toolkit_dir)
    export = export_bop24(dataset, results_csv, out_dir, progress)
    return compare_bop24(ours, evaluate_bop24(export, scripts, quiet), export)


def format_bop24_crosscheck(check: Bop24Crosscheck) -> str:
    """The seven keys side by side and the verdict."""
    lines = [f"{'key':<30} {'bop-cender':>20} {'toolkit':>20} {'|diff|':>10}"]
    for key in BOP24_KEYS:
        a, b = check.ours.get(key), check.theirs.get(key)
        diff = "n/a" if a is None or b is None else f"{abs(a - b):.1e}"
        lines.append(f"{key:<30} {_show(a):>20} {_show(b):>20} {diff:>10}")
    n_obj = sum(len(v) for v in check.object_aps.values())
    if check.agrees:
        lines.append(
            f"agree: every key and the AP of {n_obj} (error type, object) pairs per threshold within {TOLERANCE:g}"
        )
    else:
        lines.append(f"DISAGREE ({len(check.differences)}):")
        lines.extend(f"  {d}" for d in check.differences)
    return "\n".join(lines)


def _show(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.12f}"
