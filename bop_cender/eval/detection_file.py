"""Score a results CSV with the BOP'24/'25 detection protocol: ``scores_<stem>_bop24.json`` and
``detections_<stem>_bop24.csv`` (:mod:`bop_cender.eval.detection_report`).

Called by :func:`bop_cender.eval.score_file.score_file` once the data is chosen and opened (the one seam where
the protocol is chosen: ``--protocol``, else the run sidecar's ``extra.protocol``, else BOP'19).

Unlike BOP'19 scoring, rows naming objects or images the data does not hold are not refused: the toolkit's
detection protocol ignores them (they still count towards their image's cap), and its figures are what a
BOP'24 score must equal. They are counted, said in the summary and in one :class:`~bop_cender.errors.ResultsWarning`;
a file none of whose rows is evaluated is refused (its mAP of 0 would only say that file and data do not belong
together).
"""

from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

from bop_cender.data.types import Dataset
from bop_cender.errors import ResultsError, ResultsWarning
from bop_cender.eval.detection_report import DetectionReport
from bop_cender.eval.scoring_bop24 import score_detections
from bop_cender.results.bop_csv import BopEstimate

#: The protocols ``bop-cender score`` implements, the default first.
PROTOCOLS = ("bop19", "bop24")
#: Below this fraction of rows evaluated (not cut, not ignored), scoring warns.
MIN_EVALUATED_FRACTION = 0.5


def detection_file_outputs(csv_path: str | Path, out_dir: str | Path | None = None) -> tuple[Path, Path]:
    """``(scores_<stem>_bop24.json, detections_<stem>_bop24.csv)`` for ``csv_path`` in ``out_dir`` (default beside it):
    names of their own, so that a file scored under both protocols keeps both."""
    csv_path = Path(csv_path)
    out = Path(out_dir) if out_dir is not None else csv_path.parent
    stem = csv_path.name.split(".")[0]
    return out / f"scores_{stem}_bop24.json", out / f"detections_{stem}_bop24.csv"


def score_detection_rows(
    rows: list[BopEstimate],
    ds: Dataset,
    csv_path: Path,
    *,
    progress: bool = True,
    method: str | None = None,
    origin: str | None = None,
) -> DetectionReport:
    """BOP'24 scores of the file's rows on the opened data, checked (:func:`check_evaluated`).

    Raises:
        ResultsError: no row is evaluated.
    """
    report = replace(score_detections(rows, ds, progress=progress, source=csv_path), method=method, data_origin=origin)
    check_evaluated(report, csv_path)
    return report


def check_evaluated(report: DetectionReport, csv_path: Path) -> None:
    """Refuse a file none of whose rows is evaluated; warn (and note) when under half are or when rows name objects
    without a model or images outside the target images."""
    c = report.counts
    where = f"dataset {report.dataset} {report.split} at {report.root}"
    if c.evaluated == 0:
        raise ResultsError(
            f"0 of {c.rows} rows are evaluated on {where} ({c.cut} cut, {c.not_target_image} of non-target images,"
            f" {c.object_not_in_image} of objects their image does not hold): wrong --data-root or --split?",
            file=csv_path,
        )
    ignored = c.not_target_image + c.object_not_in_image
    if ignored:
        message = (
            f"{ignored} of {c.rows} rows ignored, as the toolkit ignores them: {c.not_target_image} of images that are"
            f" not target images, {c.object_not_in_image} of objects their image does not hold"
            + (f" ({c.unknown_object} of objects without a model)" if c.unknown_object else "")
        )
        report.notes.append(message)
        if c.evaluated / c.rows < MIN_EVALUATED_FRACTION or c.unknown_object:
            warnings.warn(f"{csv_path}: {message}", ResultsWarning, stacklevel=3)
