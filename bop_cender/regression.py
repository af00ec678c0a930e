"""The regression check: a fixed, seeded evaluation whose every number is committed under ``results/regression/``
(a folder of the repository, not of the package: callers pass it, ``scripts/regression.py`` by default).

:func:`run_regression` builds the fixture of :mod:`bop_cender.synth.regression_fixture` (T-LESS layout,
720x540, rendered depth; results with perturbations straddling the thresholds, symmetric, occluded,
duplicate and non-target estimates), scores it with the real scorer and turns the report into tables:

- ``scores.csv``: every recall (MSSD and MSPD per threshold, VSD per tau and threshold) and the six scores;
- ``errors.csv``: the raw errors of every (estimate, GT) pair (MSSD mm, MSPD px, VSD per tau);
- ``matches.csv``: per evaluated estimate, the gt_id it is matched to at each threshold (-1: none);
- ``scores_bop24.csv``: BOP'24/'25 detection on the same fixture with the rows of
  :func:`bop_cender.synth.detection_rows.detection_rows` (every rule of the cap, ties, hidden instances, ignored
  rows): per error type, object and threshold the AP, and the seven scores; its anchor
  ``toolkit_anchor_scores_bop24.csv`` is the toolkit's ``eval_bop24_pose.py`` on the same export, and every value
  must equal it (within the tables' rounding).

:func:`compare_tables` compares them with the committed ones (numbers within :data:`TOLERANCE`, i.e. the
rounding of the written tables; ids exactly) and with the official toolkit's numbers for the same fixture
(``toolkit_anchor_scores.csv``, ``toolkit_anchor_errors.csv``, made once by ``scripts/regression.py
--anchor TOOLKIT``): recalls and scores must be equal, MSSD and MSPD within 1e-9, VSD within
:data:`VSD_RENDERER_TOLERANCE` (the toolkit renders with OpenGL, whose depth differs from our exact
rasteriser's by up to ~2e-3 mm and one silhouette pixel in a few thousand).
"""

from __future__ import annotations

import csv
import io
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bop_cender.data.registry import DatasetRequest, open_dataset
from bop_cender.eval.detection import BOP24_KEYS, ERROR_TYPES
from bop_cender.eval.detection_report import DetectionReport
from bop_cender.eval.score_report import SCORE_KEYS, ScoreReport
from bop_cender.eval.scoring import score_results
from bop_cender.eval.scoring_bop24 import score_detections
from bop_cender.results.bop_csv import write_bop_results
from bop_cender.synth.detection_rows import detection_rows
from bop_cender.synth.regression_fixture import FixtureSpec, build_fixture, regression_estimates

RESULTS_NAME = "regression_tless-test.csv"
#: Digits written for errors and recalls; compared within TOLERANCE (half a unit of the last digit, plus slack).
DIGITS = 9
TOLERANCE = 1e-8
#: Our VSD vs the toolkit's (different renderers: OpenGL depth buffer vs exact rasterisation).
VSD_RENDERER_TOLERANCE = 2e-3
GEOMETRIC_TOLERANCE = 1e-9

OURS = ("scores.csv", "errors.csv", "matches.csv", "scores_bop24.csv")
ANCHOR = ("toolkit_anchor_scores.csv", "toolkit_anchor_errors.csv")
ANCHOR_BOP24 = "toolkit_anchor_scores_bop24.csv"
#: The BOP'24 rows' results file and their generator's arguments (crowded: one image crosses the cap of 100).
RESULTS_NAME_BOP24 = "regression24_tless-test.csv"
DETECTION_ROWS = {"seed": 2, "crowded": 130}


@dataclass(frozen=True)
class RegressionRun:
    """The scored fixture and its tables (file name -> CSV text)."""

    report: ScoreReport
    tables: dict[str, str]
    detection: DetectionReport | None = None


def run_regression(work_dir: str | Path | None = None, progress: bool = False) -> RegressionRun:
    """Build the fixture (in ``work_dir`` or a temporary folder), score it (BOP'19 and BOP'24), return the tables."""
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(work_dir) if work_dir is not None else Path(tmp)
        built = build_fixture(work / "tless", FixtureSpec())
        rows = regression_estimates(built)
        write_bop_results(work / RESULTS_NAME, rows, sort=False)
        dataset = open_dataset(DatasetRequest("tless", work / "tless", "test"))
        report = score_results(rows, dataset, progress=progress)
        rows24 = detection_rows(built, **DETECTION_ROWS)
        write_bop_results(work / RESULTS_NAME_BOP24, rows24, sort=False)
        detection = score_detections(rows24, dataset, progress=progress)
    tables = {**report_tables(report), "scores_bop24.csv": bop24_table(detection.scores, _object_aps(detection))}
    return RegressionRun(report, tables, detection)


def bop24_table(scores: dict, object_aps: dict[str, dict[int, list[float]]]) -> str:
    """``scores_bop24.csv``: per error type (``metric``), object and threshold the AP, then the seven scores."""
    rows = [["metric", "obj_id", "threshold", "value"]]
    for name, per_object in object_aps.items():
        ths = ERROR_TYPES[name][0]
        for obj, aps in sorted(per_object.items()):
            rows += [[name, obj, _fmt(th), _fmt(ap)] for th, ap in zip(ths, aps, strict=True)]
    rows += [[k, "", "", _fmt(scores[k])] for k in BOP24_KEYS]
    return _csv(rows)


def _object_aps(detection: DetectionReport) -> dict[str, dict[int, list[float]]]:
    return {n: {o: [c.ap for c in s.curves[o]] for o in s.objects} for n, s in detection.per_type.items()}


def report_tables(report: ScoreReport) -> dict[str, str]:
    """``scores.csv``, ``errors.csv`` and ``matches.csv`` of a report (see the module docstring)."""
    return {
        "scores.csv": scores_table(report),
        "errors.csv": errors_table(report),
        "matches.csv": matches_table(report),
    }


def scores_table(report: ScoreReport) -> str:
    rows = [["metric", "tau", "threshold", "value"]]
    for name, ths, recalls in (("mssd", report.mssd_thresholds, report.mssd_recalls),
                               ("mspd", report.mspd_thresholds, report.mspd_recalls)):  # fmt: skip
        rows += [[name, "", _fmt(th), _fmt(r)] for th, r in zip(ths, recalls, strict=True)]
    if report.vsd_recalls is not None:
        for tau, row in zip(report.vsd_taus, report.vsd_recalls, strict=True):
            rows += [["vsd", _fmt(tau), _fmt(th), _fmt(r)] for th, r in zip(report.vsd_thresholds, row, strict=True)]
    rows += [[k, "", "", _fmt(report.scores[k])] for k in SCORE_KEYS]
    return _csv(rows)


def errors_table(report: ScoreReport) -> str:
    taus = [f"vsd_{t:.2f}" for t in report.vsd_taus]
    rows = [["scene_id", "im_id", "obj_id", "est_id", "gt_id", "mssd_mm", "mspd_px", *taus]]
    for r in report.records:
        for j, gt_id in enumerate(r.gt_ids.tolist()):
            vsd = [""] * len(taus) if r.vsd is None else [_fmt(v) for v in r.vsd[j]]
            rows.append([r.scene_id, r.im_id, r.obj_id, r.est_id, gt_id, _fmt(r.mssd_mm[j]), _fmt(r.mspd_px[j]), *vsd])
    return _csv(rows)


def matches_table(report: ScoreReport) -> str:
    rows = [["scene_id", "im_id", "obj_id", "est_id", "score", "mssd_gt_per_threshold", "mspd_gt_per_threshold",
             "vsd_gt_per_tau_threshold"]]  # fmt: skip
    for r in report.records:
        vsd = "" if r.vsd_match is None else " ".join(map(str, r.vsd_match.reshape(-1).tolist()))
        rows.append([r.scene_id, r.im_id, r.obj_id, r.est_id, repr(r.score),
                     " ".join(map(str, r.mssd_match.tolist())), " ".join(map(str, r.mspd_match.tolist())), vsd])  # fmt: skip
    return _csv(rows)


def compare_tables(run: RegressionRun, tables_dir: str | Path) -> list[str]:
    """Every difference between ``run`` and the committed tables and the toolkit anchor, one line each."""
    tables_dir = Path(tables_dir)
    problems: list[str] = []
    for name in OURS:
        path = tables_dir / name
        if not path.is_file():
            problems.append(f"{name}: missing (run scripts/regression.py --update)")
            continue
        problems += _diff(name, _parse(path.read_text()), _parse(run.tables[name]), lambda col: TOLERANCE)
    anchor_scores, anchor_errors = (tables_dir / n for n in ANCHOR)
    if anchor_scores.is_file() and anchor_errors.is_file():
        problems += _diff("toolkit anchor scores", _parse(anchor_scores.read_text()), _parse(run.tables["scores.csv"]),
                          lambda col: TOLERANCE)  # fmt: skip
        problems += _diff("toolkit anchor errors", _parse(anchor_errors.read_text()), _parse(run.tables["errors.csv"]),
                          lambda col: VSD_RENDERER_TOLERANCE if col.startswith("vsd") else GEOMETRIC_TOLERANCE)  # fmt: skip
    else:
        problems.append(f"toolkit anchor missing: {', '.join(ANCHOR)} (scripts/regression.py --anchor TOOLKIT_DIR)")
    anchor24 = tables_dir / ANCHOR_BOP24
    if anchor24.is_file():
        problems += _diff("toolkit anchor BOP'24 scores", _parse(anchor24.read_text()),
                          _parse(run.tables["scores_bop24.csv"]), lambda col: TOLERANCE)  # fmt: skip
    else:
        problems.append(f"toolkit anchor missing: {ANCHOR_BOP24} (scripts/regression.py --anchor TOOLKIT_DIR)")
    return problems


def write_tables(run: RegressionRun, tables_dir: str | Path) -> list[Path]:
    """Write our tables (not the anchor) into ``tables_dir``."""
    from bop_cender.data.bop_io import write_text_atomic

    paths = []
    for name in OURS:
        path = Path(tables_dir) / name
        write_text_atomic(path, run.tables[name])
        paths.append(path)
    return paths


def anchor_tables(
    errors: dict[str, dict[tuple, list[float]]], recalls: dict[str, list[float]], averages: dict
) -> dict[str, str]:
    """The toolkit's numbers in the layout of ``scores.csv`` / ``errors.csv`` (see runtime.ToolkitScores)."""
    from bop_cender.eval.matching import MSPD_THRESHOLDS, MSSD_THRESHOLDS, VSD_THRESHOLDS
    from bop_cender.eval.vsd import VSD_TAUS

    rows = [["metric", "tau", "threshold", "value"]]
    rows += [["mssd", "", _fmt(th), _fmt(r)] for th, r in zip(MSSD_THRESHOLDS, recalls["mssd"], strict=True)]
    rows += [["mspd", "", _fmt(th), _fmt(r)] for th, r in zip(MSPD_THRESHOLDS, recalls["mspd"], strict=True)]
    vsd = np.asarray(recalls["vsd"]).reshape(len(VSD_TAUS), len(VSD_THRESHOLDS))
    for tau, row in zip(VSD_TAUS, vsd, strict=True):
        rows += [["vsd", _fmt(tau), _fmt(th), _fmt(r)] for th, r in zip(VSD_THRESHOLDS, row, strict=True)]
    mssd, mspd = recalls["mssd"], recalls["mspd"]
    ar = {"AR": averages["bop19"], "AR_VSD": averages["vsd"], "AR_MSSD": averages["mssd"], "AR_MSPD": averages["mspd"],
          "AR_MSPD<5px": mspd[0], "AR_MSSD<5%": mssd[0]}  # fmt: skip
    rows += [[k, "", "", _fmt(ar[k])] for k in SCORE_KEYS]
    taus = [f"vsd_{t:.2f}" for t in VSD_TAUS]
    err_rows = [["scene_id", "im_id", "obj_id", "est_id", "gt_id", "mssd_mm", "mspd_px", *taus]]
    for key in sorted(errors["mssd"]):
        err_rows.append(
            [*key, _fmt(errors["mssd"][key][0]), _fmt(errors["mspd"][key][0]), *map(_fmt, errors["vsd"][key])]
        )
    return {ANCHOR[0]: _csv(rows), ANCHOR[1]: _csv(err_rows)}


def format_problems(problems: list[str], limit: int = 40) -> str:
    """A diff table: one line per difference (the first ``limit``)."""
    head = f"{len(problems)} difference(s) from the committed regression tables:"
    more = [f"... and {len(problems) - limit} more"] if len(problems) > limit else []
    return "\n".join([head, *(f"  {p}" for p in problems[:limit]), *more])


# --------------------------------------------------------------------------------------------- helpers

_Table = tuple[list[str], dict[tuple, dict[str, str]]]
_KEY_COLUMNS = ("scene_id", "im_id", "obj_id", "est_id", "gt_id", "metric", "tau", "threshold")  # obj_id: BOP'24


def _parse(text: str) -> _Table:
    """CSV text -> (header, rows keyed by their id columns)."""
    reader = list(csv.reader(io.StringIO(text)))
    header, body = reader[0], reader[1:]
    keys = [i for i, h in enumerate(header) if h in _KEY_COLUMNS]
    return header, {tuple(row[i] for i in keys): dict(zip(header, row, strict=True)) for row in body}


def _diff(name: str, expected: _Table, actual: _Table, tolerance) -> list[str]:
    """Lines ``name: key: column: expected X, got Y`` for every difference."""
    (h_exp, exp), (h_act, act) = expected, actual
    out = []
    if h_exp != h_act:
        return [f"{name}: columns differ: expected {h_exp}, got {h_act}"]
    for key in sorted(set(exp) | set(act)):
        if key not in act:
            out.append(f"{name}: {'/'.join(key)}: row missing")
            continue
        if key not in exp:
            out.append(f"{name}: {'/'.join(key)}: unexpected row")
            continue
        for col in h_exp:
            a, b = exp[key][col], act[key][col]
            if a != b and not _close(a, b, tolerance(col)):
                out.append(f"{name}: {'/'.join(key)}: {col}: expected {a}, got {b}")
    return out


def _close(a: str, b: str, tol: float) -> bool:
    try:
        x, y = float(a), float(b)
    except ValueError:
        return False
    if math.isinf(x) or math.isinf(y):
        return x == y
    return abs(x - y) <= tol


def _fmt(value: float) -> str:
    value = float(value)
    if math.isinf(value):
        return "inf"
    return f"{round(value, DIGITS) + 0.0:.{DIGITS}f}"


def _csv(rows: list[list]) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(rows)
    return buf.getvalue()
