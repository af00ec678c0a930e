"""What scoring produces (:class:`ScoreReport`) and how it is written: scores JSON, errors CSV.

``scores_<stem>.json`` has at its top level the six scores under exactly these names (``null`` where
not available, e.g. VSD and AR without test depth), then ``recalls`` (per threshold) and
``metadata`` (dataset, split, MSPD width, VSD delta, targets source, counts, time per image, notes).
``errors_<stem>.csv`` has one row per evaluated estimate (see :func:`write_errors_csv`).
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from bop_cender.data.bop_io import load_json, write_text_atomic, write_texts_atomic
from bop_cender.eval.ground_truth import GroundTruth
from bop_cender.eval.matching import Matches

#: The scores, in the order they are printed and written.
SCORE_KEYS = ("AR", "AR_VSD", "AR_MSSD", "AR_MSPD", "AR_MSPD<5px", "AR_MSSD<5%")
SCORES_FORMAT = "bop-cender-scores"
#: How far a scores JSON's AR may be from the mean of its three parts (figures rounded to three decimals pass).
AR_MEAN_TOLERANCE = 1e-3


@dataclass(frozen=True, eq=False)
class EstimateRecord:
    """Errors and matches of one evaluated (kept) estimate against the GTs of its object in its image.

    Attributes:
        scene_id, im_id, obj_id: the estimate's image and object (BOP int scene id).
        est_id: index within its (scene, image, object) group in file order (the toolkit's est_id).
        score: confidence. line: line in the results file (None for in-memory rows).
        gt_ids: ``(G,)`` gt_ids of the GT instances of this object in the image.
        mssd_mm, mspd_px: ``(G,)`` raw errors (``inf`` = MSSD early-out). mssd, mspd: ``(G,)``
            normalised (MSSD / diameter, MSPD x 640 / width).
        vsd: ``(G, taus)`` VSD errors, None without test depth.
        mssd_match, mspd_match: ``(thresholds,)`` gt_id matched at each threshold, -1 if none.
        vsd_match: ``(taus, thresholds)`` likewise, None without test depth.
    """

    scene_id: int
    im_id: int
    obj_id: int
    est_id: int
    score: float
    line: int | None
    gt_ids: np.ndarray
    mssd_mm: np.ndarray
    mssd: np.ndarray
    mspd_px: np.ndarray
    mspd: np.ndarray
    vsd: np.ndarray | None
    mssd_match: np.ndarray
    mspd_match: np.ndarray
    vsd_match: np.ndarray | None

    def best_gt(self) -> int:
        """Index into ``gt_ids`` of the closest GT: lowest MSSD, then MSPD, then gt_id."""
        return int(np.lexsort((self.gt_ids, self.mspd, self.mssd))[0])


@dataclass(frozen=True)
class ScoreCounts:
    """How many of each the scorer saw (the scores JSON's ``metadata.counts``).

    Attributes:
        rows: rows of the results. not_target: rows for non-target images/objects (ignored, no penalty).
        unselected_images: rows for images on disk that the split did not select (ignored, as the toolkit does).
        evaluated: rows kept by the top-n cut. beyond_top_n: rows of targets beyond their top-n.
        pairs: (estimate, GT) pairs scored. targets: (image, object) targets. target_instances: recall's
        denominator. target_images: images with a target.
        missed_instances: target instances no estimate matches at the loosest MSSD threshold.
        unmatched_not_visible, unmatched_duplicate, unmatched_far: why evaluated estimates match nothing at
        that threshold: their closest instance is not a target (too little of it visible, or beyond its
        image's ``inst_count`` most visible), another estimate took it, or it is farther than every threshold.
        Why perfect poses can score below 1 (:func:`bop_cender.eval.score_rows.unmatched_reasons`).
    """

    rows: int
    not_target: int
    unselected_images: int
    evaluated: int
    beyond_top_n: int
    pairs: int
    targets: int
    target_instances: int
    target_images: int
    missed_instances: int = 0
    unmatched_not_visible: int = 0
    unmatched_duplicate: int = 0
    unmatched_far: int = 0


@dataclass(frozen=True)
class ScoreMetadata:
    """What a score was computed on and how (the scores JSON's ``metadata``, in this order).

    Attributes:
        dataset, split, root: the dataset split. results: the results file (None for in-memory rows).
        n_top: the top-n rule. mspd_width, mspd_width_source: the width MSPD is normalised by, and why.
        vsd_delta, vsd_delta_source: VSD's delta (mm) and why; None without test depth.
        vsd_renders: who rendered VSD's depth. targets_source, targets_note: where the targets came from.
        gt_pose_source: where the GT poses came from. counts: :class:`ScoreCounts`.
        time_per_image: the BOP average time per image (s), None if a row has time < 0.
        data_origin: where the data settings came from (set by :func:`~bop_cender.eval.score_file.score_file`).
        method: the method's name (likewise).
    """

    dataset: str
    split: str
    root: str
    results: str | None
    n_top: int
    mspd_width: float
    mspd_width_source: str
    vsd_delta: float | None
    vsd_delta_source: str | None
    vsd_renders: str | None
    targets_source: str
    targets_note: str
    gt_pose_source: str
    counts: ScoreCounts
    time_per_image: float | None
    data_origin: str | None = None
    method: str | None = None

    def to_json(self) -> dict[str, Any]:
        """JSON-ready values, keys in field order (``data_origin`` and ``method`` only when set)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if value is None and f.name in ("data_origin", "method"):
                continue
            out[f.name] = asdict(value) if f.name == "counts" else value
        return out


@dataclass(frozen=True, eq=False)
class ScoreReport:
    """BOP'19 localisation scores of one results file on one dataset split, with everything behind them.

    Attributes:
        scores: the six scores by :data:`SCORE_KEYS` name; None where not available.
        mssd_thresholds, mspd_thresholds: ``(K,)``; vsd_taus, vsd_thresholds: ``(T,)``, ``(K,)``.
        mssd_recalls, mspd_recalls: ``(K,)``; vsd_recalls: ``(T, K)`` or None.
        metadata: what the scores were computed on and how (:class:`ScoreMetadata`).
        notes: human-readable lines on what was done and why.
        records: one per evaluated estimate.
        timings: seconds per stage.
        matches: the greedy matches per metric (``mssd``, ``mspd``, ``vsd`` with depth) over the valid GTs, kept so
            that recall can be broken down per object or scene (``bop-cender report``) without scoring again; not
            written to the scores JSON.
        ground_truth: the split's ground truth the file was scored against (the report page's images and scenes,
            without reading the split again); not written.
    """

    scores: dict[str, float | None]
    mssd_thresholds: np.ndarray
    mspd_thresholds: np.ndarray
    vsd_taus: np.ndarray
    vsd_thresholds: np.ndarray
    mssd_recalls: np.ndarray
    mspd_recalls: np.ndarray
    vsd_recalls: np.ndarray | None
    metadata: ScoreMetadata
    notes: list[str] = field(default_factory=list)
    records: list[EstimateRecord] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    matches: dict[str, Matches] = field(default_factory=dict)
    ground_truth: GroundTruth | None = field(default=None, repr=False, compare=False)

    def to_json(self) -> dict[str, Any]:
        """The scores JSON content (see the module docstring)."""
        recalls: dict[str, Any] = {
            "mssd": {"thresholds": self.mssd_thresholds.tolist(), "recall": self.mssd_recalls.tolist()},
            "mspd": {"thresholds": self.mspd_thresholds.tolist(), "recall": self.mspd_recalls.tolist()},
            "vsd": None
            if self.vsd_recalls is None
            else {
                "taus": self.vsd_taus.tolist(),
                "thresholds": self.vsd_thresholds.tolist(),
                "recall": self.vsd_recalls.tolist(),
            },
        }
        meta = {
            "format": SCORES_FORMAT,
            **self.metadata.to_json(),
            "notes": list(self.notes),
            "timings": dict(self.timings),
        }
        return {**{k: self.scores.get(k) for k in SCORE_KEYS}, "recalls": recalls, "metadata": meta}


def scores_json_text(report: ScoreReport) -> str:
    """:meth:`ScoreReport.to_json` as strict JSON text (non-finite numbers become null)."""
    return json.dumps(finite_json(report.to_json()), indent=1) + "\n"


def write_scores_json(path: str | Path, report: ScoreReport) -> None:
    """Write :func:`scores_json_text` atomically."""
    write_text_atomic(path, scores_json_text(report))


def write_score_files(scores_path: str | Path, errors_path: str | Path, report: ScoreReport) -> None:
    """Write the scores JSON and the errors CSV of one report as a unit: both, or neither (the previous
    pair kept), so that a scores file never sits beside the errors of another scoring."""
    write_texts_atomic({errors_path: errors_csv_text(report), scores_path: scores_json_text(report)})


def is_recall(value: object) -> bool:
    """Whether ``value`` can be one of :data:`SCORE_KEYS`: a number in [0, 1] (every BOP score is a recall)."""
    return isinstance(value, int | float) and not isinstance(value, bool) and 0.0 <= value <= 1.0  # NaN fails


def read_scores_json(path: str | Path) -> dict[str, Any]:
    """A scores JSON written by :func:`write_scores_json`: the six score keys (numbers or null) and string metadata."""
    from bop_cender.errors import ResultsError

    path = Path(path)
    data = load_json(path, error=ResultsError)
    missing = [k for k in SCORE_KEYS if not isinstance(data, dict) or k not in data]
    if missing:
        raise ResultsError(f"not a scores file: missing {', '.join(missing)}", file=path)
    for key in SCORE_KEYS:
        value = data[key]
        if value is not None and not is_recall(value):
            raise ResultsError(f"expected a recall in [0, 1] or null, got {value!r}", file=path, field=key)
    parts = [data[k] for k in ("AR_VSD", "AR_MSSD", "AR_MSPD")]
    if None in parts and data["AR"] is not None:
        raise ResultsError(f"AR is {data['AR']!r} but AR_VSD, AR_MSSD or AR_MSPD is null: expected null (AR is their mean)",
                           file=path, field="AR")  # fmt: skip
    if None not in parts and (data["AR"] is None or abs(data["AR"] - sum(parts) / 3) > AR_MEAN_TOLERANCE):
        raise ResultsError(f"AR is {data['AR']!r}, not the mean of AR_VSD, AR_MSSD and AR_MSPD ({sum(parts) / 3:.6g})",
                           file=path, field="AR")  # fmt: skip
    meta = data.get("metadata")
    if meta is not None and not isinstance(meta, dict):
        raise ResultsError(f"expected an object, got {type(meta).__name__}", file=path, field="metadata")
    for key in ("method", "dataset", "split"):
        if meta and meta.get(key) is not None and not isinstance(meta[key], str):
            raise ResultsError(f"expected a string, got {meta[key]!r}", file=path, field=f"metadata.{key}")
    return data


def errors_csv_text(report: ScoreReport) -> str:
    """One row per evaluated estimate.

    Columns: ``scene_id, im_id, obj_id, est_id, line, score``; ``gt_id``: the GT the estimate is
    matched to by MSSD at the loosest threshold, -1 if none; ``errors_gt_id``: the GT the error
    columns refer to (the matched one, else the closest by MSSD); ``mssd_mm, mssd, mspd_px, mspd``
    (raw and normalised); ``vsd_<tau>`` per tau (empty without depth); ``mssd_hits, mspd_hits,
    vsd_hits``: at how many thresholds (VSD: tau x threshold pairs) the estimate matches a GT.
    """
    taus = [f"vsd_{t:.2f}" for t in report.vsd_taus]
    header = ["scene_id", "im_id", "obj_id", "est_id", "line", "score", "gt_id", "errors_gt_id"]
    header += ["mssd_mm", "mssd", "mspd_px", "mspd", *taus, "mssd_hits", "mspd_hits", "vsd_hits"]
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(header)
    for r in report.records:
        matched = int(r.mssd_match[-1])
        j = int(np.flatnonzero(r.gt_ids == matched)[0]) if matched >= 0 else r.best_gt()
        vsd = [""] * len(taus) if r.vsd is None else [number_text(v) for v in r.vsd[j]]
        hits = [int(np.count_nonzero(m >= 0)) if m is not None else "" for m in (r.mssd_match, r.mspd_match)]
        vsd_hits = "" if r.vsd_match is None else int(np.count_nonzero(r.vsd_match >= 0))
        writer.writerow(
            [r.scene_id, r.im_id, r.obj_id, r.est_id, "" if r.line is None else r.line, repr(r.score), matched]
            + [
                int(r.gt_ids[j]),
                number_text(r.mssd_mm[j]),
                number_text(r.mssd[j]),
                number_text(r.mspd_px[j]),
                number_text(r.mspd[j]),
            ]
            + vsd
            + [*hits, vsd_hits]
        )
    return buf.getvalue()


def write_errors_csv(path: str | Path, report: ScoreReport) -> None:
    """Write :func:`errors_csv_text` atomically."""
    write_text_atomic(path, errors_csv_text(report))


def number_text(value: float) -> str:
    return "inf" if math.isinf(value) else repr(float(value))


def finite_json(obj: Any) -> Any:
    """JSON-safe copy: non-finite floats become None (the toolkit writes ``Infinity``; strict JSON cannot)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_json(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [finite_json(v) for v in obj]
    return obj
