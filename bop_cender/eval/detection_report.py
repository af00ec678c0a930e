"""What BOP'24 detection scoring produces (:class:`DetectionReport`) and how it is written and explained.

``scores_<stem>_bop24.json`` has at its top level the toolkit's seven keys under exactly its names
(:data:`~bop_cender.eval.detection.BOP24_KEYS`; ``bop24_average_time_per_image`` is -1.0 when a time is unknown,
as the toolkit writes it), then ``protocol``, ``per_object`` (per error type and object: its mAP, its AP per
threshold, GT instances, true and false positives), ``precision_recall`` (per error type, object and threshold the
101 interpolated precisions at ``recall_points``) and ``metadata``. ``detections_<stem>_bop24.csv`` has one row per
evaluated estimate (:func:`detections_csv_text`).
"""

from __future__ import annotations

import csv
import io
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bop_cender.data.bop_io import write_texts_atomic
from bop_cender.eval.detection import BOP24_KEYS, RECALL_POINTS, ErrorTypeScores
from bop_cender.eval.ground_truth import GroundTruth
from bop_cender.eval.score_report import finite_json, number_text

#: The ``protocol`` value of a BOP'24 scores JSON.
PROTOCOL = "bop24"
SCORES_FORMAT = "bop-cender-scores-bop24"


@dataclass(frozen=True)
class DetectionCounts:
    """What happened to the rows (the scores JSON's ``metadata.counts``).

    Attributes:
        rows: rows of the results. cut: rows beyond their image's ``cap`` best-scored. cap: the cap per image.
        not_target_image: kept rows of images that are not target images (ignored, as the toolkit does).
        object_not_in_image: kept rows of a target image whose object it does not hold (ignored, as the toolkit
            does: neither hit nor false positive). unknown_object: rows whose object the dataset has no model of
            (among the two above).
        evaluated: the estimates scored. pairs: (estimate, GT instance) pairs. target_images: images evaluated.
        gt_instances: GT instances at least 10 % visible (recall's denominators, summed over objects).
        gt_instances_hidden: GT instances under 10 % visible (neither hits nor misses).
    """

    rows: int
    cut: int
    cap: int
    not_target_image: int
    object_not_in_image: int
    unknown_object: int
    evaluated: int
    pairs: int
    target_images: int
    gt_instances: int
    gt_instances_hidden: int


@dataclass(frozen=True, eq=False)
class EvaluatedEstimate:
    """One evaluated estimate: its closest GT instance (lowest MSSD) and errors, and per error type and threshold
    whether it counted as a true positive (1), a false positive (0) or was left out (-1, matched to a GT instance
    under 10 % visible).

    Attributes:
        errors: ``(mssd_mm, mssd, mspd)`` against ``gt_id``; None when the image holds no GT instance of the object.
        status: error type -> ``(K,)`` int8.
    """

    scene_id: int
    im_id: int
    obj_id: int
    score: float
    line: int | None
    gt_id: int
    errors: tuple[float, float, float] | None
    status: dict[str, np.ndarray]


@dataclass(frozen=True, eq=False)
class DetectionReport:
    """BOP'24/'25 detection scores of one results file on one dataset split, with everything behind them."""

    scores: dict[str, float | None]
    per_type: dict[str, ErrorTypeScores]
    counts: DetectionCounts
    dataset: str
    split: str
    root: str
    results: str | None
    targets_source: str
    targets_note: str
    visib_source: str
    mspd_width: float
    mspd_width_source: str
    gt_pose_source: str
    records: list[EvaluatedEstimate] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    method: str | None = None
    data_origin: str | None = None
    #: ``(scene_id, im_id, gt_id, obj_id)`` of every GT instance at least 10 % visible in the target images (recall's
    #: denominators), kept so that recall can be broken down per scene (``bop-cender report``); not in the JSON.
    visible_gts: tuple[tuple[int, int, int, int], ...] = ()
    #: the split's ground truth the file was scored against (the report page's images and scenes); not in the JSON.
    ground_truth: GroundTruth | None = field(default=None, repr=False, compare=False)

    def to_json(self) -> dict[str, Any]:
        """The scores JSON content (module docstring)."""
        per_object: dict[str, Any] = {}
        curves: dict[str, Any] = {"recall_points": RECALL_POINTS.tolist()}
        for name, s in self.per_type.items():
            per_object[name] = {
                "thresholds": s.thresholds.tolist(),
                "objects": {
                    str(o): {
                        "mAP": s.object_ap[o],
                        "AP": [c.ap for c in s.curves[o]],
                        "gt_instances": s.curves[o][0].n_gts,
                        "true_positives": [c.true_positives for c in s.curves[o]],
                        "false_positives": [c.false_positives for c in s.curves[o]],
                    }
                    for o in s.objects
                },
            }
            curves[name] = {str(o): [c.precisions.tolist() for c in s.curves[o]] for o in s.objects}
        meta = {
            "format": SCORES_FORMAT,
            "dataset": self.dataset,
            "split": self.split,
            "root": self.root,
            "results": self.results,
            **({"method": self.method} if self.method else {}),
            **({"data_origin": self.data_origin} if self.data_origin else {}),
            "targets_source": self.targets_source,
            "targets_note": self.targets_note,
            "visib_source": self.visib_source,
            "mspd_width": self.mspd_width,
            "mspd_width_source": self.mspd_width_source,
            "gt_pose_source": self.gt_pose_source,
            "counts": asdict(self.counts),
            "notes": list(self.notes),
            "timings": dict(self.timings),
        }
        return {
            **{k: self.scores[k] for k in BOP24_KEYS},
            "protocol": PROTOCOL,
            "per_object": per_object,
            "precision_recall": curves,
            "metadata": meta,
        }

    def summary_lines(self) -> list[str]:
        """What the figures are made of, for the terminal: rows cut and ignored, estimates per kind, AP per object."""
        c = self.counts
        lines = [
            f"protocol: BOP'24/'25 6D detection (the toolkit's eval_bop24_pose.py); {self.targets_note}",
            f"rows: {c.rows}; cut beyond the {c.cap} best-scored per image: {c.cut}; ignored: {c.not_target_image}"
            f" of non-target images, {c.object_not_in_image} of objects their image does not hold"
            + (f" ({c.unknown_object} of objects without a model)" if c.unknown_object else "")
            + f"; evaluated: {c.evaluated}",
            f"GT instances: {c.gt_instances} at least 10 % visible in {c.target_images} images; {c.gt_instances_hidden}"
            " less visible (neither hit nor miss; an estimate matched to one is left out)",
        ]
        mssd = self.per_type["mssd"]
        loosest, strictest = len(mssd.thresholds) - 1, 0
        tp = sum(mssd.curves[o][loosest].true_positives for o in mssd.objects)
        fp = sum(mssd.curves[o][loosest].false_positives for o in mssd.objects)
        tp5 = sum(mssd.curves[o][strictest].true_positives for o in mssd.objects)
        lines.append(
            f"MSSD < {mssd.thresholds[loosest]:g} diameter: {tp} true positives, {fp} false positives;"
            f" < {mssd.thresholds[strictest]:g}: {tp5} true positives"
        )
        parts = [f"{o}: {mssd.object_ap[o]:.3f}" for o in mssd.objects]
        lines.append("MSSD mAP per object: " + ", ".join(parts[:30]) + (" ..." if len(parts) > 30 else ""))
        time = self.scores["bop24_average_time_per_image"]
        lines.append(
            "time per image: " + ("unknown (a row has time -1)" if time is None or time < 0 else f"{time:.3f} s")
        )
        lines.extend(self.notes)
        return lines


def read_detection_scores_json(path: str | Path) -> dict[str, Any]:
    """A BOP'24 scores JSON (:func:`scores_json_text`): the seven keys, each mAP in [0, 1] or null, the time a number.

    Raises:
        ResultsError: not JSON, not a BOP'24 scores file, or a key of the wrong value (the key named).
    """
    from bop_cender.data.bop_io import load_json
    from bop_cender.errors import ResultsError
    from bop_cender.eval.score_report import is_recall

    data = load_json(Path(path), error=ResultsError)
    if not isinstance(data, dict) or data.get("protocol") != PROTOCOL:
        raise ResultsError(f'not a BOP\'24 scores file (expected "protocol": "{PROTOCOL}")', file=path)
    missing = [k for k in BOP24_KEYS if k not in data]
    if missing:
        raise ResultsError(f"not a BOP'24 scores file: missing {', '.join(missing)}", file=path)
    for key in BOP24_KEYS[:-1]:
        if data[key] is not None and not is_recall(data[key]):
            raise ResultsError(f"expected a mAP in [0, 1] or null, got {data[key]!r}", file=path, field=key)
    time = data[BOP24_KEYS[-1]]
    if isinstance(time, bool) or not isinstance(time, int | float):
        raise ResultsError(f"expected seconds (or -1), got {time!r}", file=path, field=BOP24_KEYS[-1])
    meta = data.get("metadata")
    if meta is not None and not isinstance(meta, dict):
        raise ResultsError(f"expected an object, got {type(meta).__name__}", file=path, field="metadata")
    return data


def scores_json_text(report: DetectionReport) -> str:
    """:meth:`DetectionReport.to_json` as strict JSON text."""
    return json.dumps(finite_json(report.to_json()), indent=1) + "\n"


def detections_csv_text(report: DetectionReport) -> str:
    """One row per evaluated estimate: ``scene_id, im_id, obj_id, line, score``; ``gt_id``: its closest GT instance
    by MSSD; ``mssd_mm, mssd, mspd`` against it (MSSD / diameter, MSPD x 640 / width); per error type the number of
    thresholds at which it is a true positive (``*_tp``) and at which it is left out (``*_left_out``)."""
    names = list(report.per_type)
    header = ["scene_id", "im_id", "obj_id", "line", "score", "gt_id", "mssd_mm", "mssd", "mspd"]
    header += [f"{n}_{kind}" for n in names for kind in ("tp", "left_out")]
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(header)
    for r in report.records:
        errs = ["", "", ""] if r.errors is None else [number_text(v) for v in r.errors]
        counts = [int(np.count_nonzero(r.status[n] == v)) for n in names for v in (1, -1)]
        writer.writerow(
            [r.scene_id, r.im_id, r.obj_id, "" if r.line is None else r.line, repr(r.score), r.gt_id, *errs, *counts]
        )
    return buf.getvalue()


def write_detection_files(scores_path: str | Path, detections_path: str | Path, report: DetectionReport) -> None:
    """Write the scores JSON and the detections CSV as a unit: both, or neither."""
    write_texts_atomic({detections_path: detections_csv_text(report), scores_path: scores_json_text(report)})
