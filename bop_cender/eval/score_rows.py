"""The scorer's bookkeeping per results row: rows checked against the split, and one record per evaluated estimate.

Used by :mod:`bop_cender.eval.scoring` (the gather and report steps).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from bop_cender.data.bop_io import few_ids
from bop_cender.data.types import Dataset
from bop_cender.errors import ResultsError
from bop_cender.eval.ground_truth import GroundTruth
from bop_cender.eval.matching import Matches, Target
from bop_cender.eval.score_report import EstimateRecord
from bop_cender.results.bop_csv import BopEstimate


def check_rows(rows: Sequence[BopEstimate], gt: GroundTruth, dataset: Dataset, source: str | Path | None) -> int:
    """Raise one ResultsError listing every row with an unknown object, scene or image; count ignored rows.

    Returns:
        rows for images that exist in the split but were not selected (ignored, as the toolkit does).
    """
    problems: list[str] = []
    ignored = 0
    known: dict[tuple[int, int], bool] = {}
    for k, row in enumerate(rows):
        where = f"line {row.line}" if row.line is not None else f"row {k}"
        if row.obj_id not in dataset.models:
            problems.append(f"{where}: obj_id: unknown object {row.obj_id} (known: {few_ids(sorted(dataset.models))})")
            continue
        key = (row.scene_id, row.im_id)
        if key in gt.images:
            continue
        if key not in known:
            known[key] = gt.image_on_disk(*key)
        if known[key]:
            ignored += 1
        elif not gt.scene_on_disk(row.scene_id):
            problems.append(f"{where}: scene_id: no scene {row.scene_id} in {dataset.name} {dataset.split}")
        else:
            problems.append(f"{where}: im_id: scene {row.scene_id} has no image {row.im_id}")
    if problems:
        raise ResultsError(
            f"{len(problems)} row(s) name data that is not in {dataset.name} {dataset.split} at {dataset.root}"
            " (were the results made on other data?)",
            file=source,
            problems=problems,
        )
    return ignored


def count_not_target(rows: Sequence[BopEstimate], targets: list[Target]) -> int:
    """Rows whose (image, object) is not a target (ignored without penalty)."""
    keys = {(t.scene_id, t.im_id, t.obj_id) for t in targets}
    return sum(1 for r in rows if (r.scene_id, r.im_id, r.obj_id) not in keys)


def unmatched_reasons(records: Sequence[EstimateRecord], valid: Matches) -> dict[str, int]:
    """Why evaluated estimates match no target instance at the loosest MSSD threshold, counted per cause.

    Ground-truth poses themselves can score below 1, correctly (the toolkit agrees): a target keeps its
    ``inst_count`` best estimates (ties in file order), so the pose of an instance that is too little
    visible to be a target can take the place of a target instance's. Each unmatched estimate is put
    under one cause by its closest instance (lowest MSSD): not a valid target (``not_visible``), valid
    but matched by another estimate (``duplicate``), or valid and farther than every threshold (``far``).

    Returns:
        ``missed`` (valid instances matched by none) and the three causes.
    """
    loosest = float(valid.thresholds[-1])
    valid_keys = {g.key for g in valid.gts}
    counts = {"missed": int(np.count_nonzero(valid.est_ids[0, -1] < 0)), "not_visible": 0, "duplicate": 0, "far": 0}
    for r in records:
        if r.mssd_match[-1] >= 0:
            continue
        if len(r.gt_ids) == 0:
            counts["far"] += 1
            continue
        j = r.best_gt()
        if (r.scene_id, r.im_id, int(r.gt_ids[j])) not in valid_keys:
            counts["not_visible"] += 1
        elif r.mssd[j] < loosest:
            counts["duplicate"] += 1
        else:
            counts["far"] += 1
    return counts


def estimate_records(kept, pairs, raw, mssd_n, mspd_n, m_mssd, m_mspd, m_vsd) -> list[EstimateRecord]:
    """One EstimateRecord per kept estimate, with the gt_id it matched per threshold."""
    group_of = {(s.estimate.scene_id, s.estimate.im_id, s.estimate.obj_id, s.est_id): k for k, s in enumerate(kept)}
    matched = {name: matched_gt(m, group_of, len(kept)) for name, m in (("mssd", m_mssd), ("mspd", m_mspd))}
    vsd_matched = None if m_vsd is None else matched_gt(m_vsd, group_of, len(kept))
    rows_of: list[list[int]] = [[] for _ in kept]
    for p in range(len(pairs)):
        rows_of[int(pairs.est[p])].append(p)
    records = []
    for k, sel in enumerate(kept):
        r = np.asarray(rows_of[k], dtype=np.int64)
        row = sel.estimate
        records.append(
            EstimateRecord(
                scene_id=row.scene_id,
                im_id=row.im_id,
                obj_id=row.obj_id,
                est_id=sel.est_id,
                score=row.score,
                line=row.line,
                gt_ids=pairs.gt_id[r],
                mssd_mm=raw.mssd[r],
                mssd=mssd_n[r],
                mspd_px=raw.mspd[r],
                mspd=mspd_n[r],
                vsd=None if raw.vsd is None else raw.vsd[r],
                mssd_match=matched["mssd"][k, 0],
                mspd_match=matched["mspd"][k, 0],
                vsd_match=None if vsd_matched is None else vsd_matched[k],
            )
        )
    return records


def matched_gt(m: Matches, group_of: dict[tuple, int], n: int) -> np.ndarray:
    """``(n, V, K)`` gt_id each kept estimate is matched to per (variant, threshold), -1 if none."""
    V, K, _ = m.est_ids.shape
    out = np.full((n, V, K), -1, dtype=np.int64)
    v, k, j = np.nonzero(m.est_ids >= 0)
    for vv, kk, jj in zip(v.tolist(), k.tolist(), j.tolist(), strict=True):
        g = m.gts[jj]
        out[group_of[(g.scene_id, g.im_id, g.obj_id, int(m.est_ids[vv, kk, jj]))], vv, kk] = g.gt_id
    return out
