"""A scored file's recall broken down per object and per scene, and the verdict of each row (``bop-cender report``).

Everything here is read off what the scorer already decided (:class:`~bop_cender.eval.score_report.ScoreReport`'s
matches, :class:`~bop_cender.eval.detection_report.DetectionReport`'s per-threshold status), never judged again: the
breakdowns add up to the scores ``bop-cender score`` prints, and a green outline on the page is a hit of the score.

The measure that ranks the scenes (worst first) is the scene's own recall:

- BOP'19: the scene's AR, the mean over its valid GT instances and over the thresholds of MSSD, MSPD (and VSD where
  the data has depth) of "matched", the AR of the file restricted to the scene's targets;
- BOP'24: the mean over the MSSD and MSPD thresholds of the scene's true positives over its GT instances at least
  10 % visible (the recall behind the mAP; the mAP itself needs the whole split's ranking).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from bop_cender.eval.detection_report import DetectionReport
from bop_cender.eval.score_report import ScoreReport

#: What a row's outline says: matched at the strictest MSSD threshold (5 % of the diameter), evaluated and not
#: matched there, or (BOP'24) matched to a GT instance under 10 % visible, neither hit nor miss.
RIGHT, WRONG, LEFT_OUT = "right", "wrong", "left out"

#: The per-object columns of each protocol, in the page's order (BOP'19: recalls; BOP'24: mAPs and recall).
OBJECT_COLUMNS_BOP19 = ("AR_VSD", "AR_MSSD", "AR_MSPD", "AR_MSSD<5%", "AR_MSPD<5px")
OBJECT_COLUMNS_BOP24 = ("mAP_mssd", "mAP_mssd_mm", "mAP_mspd", "recall_mssd")


@dataclass(frozen=True)
class Group:
    """One object's or one scene's share of the score.

    Attributes:
        key: the object id (as text) or the scene key.
        instances: its GT instances that count (BOP'19: valid targets; BOP'24: at least 10 % visible).
        values: per column (:data:`OBJECT_COLUMNS_BOP19` / ``_BOP24``, or ``measure``), None where not available.
        measure: the scene's recall that ranks it (module docstring); None without any instance.
    """

    key: str
    instances: int
    values: dict[str, float | None]
    measure: float | None = None


@dataclass(frozen=True)
class Verdicts:
    """Per results-file line, its verdict (:data:`RIGHT`, :data:`WRONG`, :data:`LEFT_OUT`; lines the scorer did not
    evaluate are absent), and per image ``(scene_id, im_id)`` the gt_ids of the counted instances no row matched at
    the strictest MSSD threshold."""

    rows: dict[int, str]
    missed: dict[tuple[int, int], set[int]]


def _mean_by(labels: list, values: np.ndarray) -> dict:
    """Mean of ``values (N,)`` per label (labels in first-seen order), with one bincount rather than a loop per label."""
    names = list(dict.fromkeys(labels))
    index = np.array([names.index(x) for x in labels], dtype=np.int64) if labels else np.zeros(0, np.int64)
    sums = np.bincount(index, weights=values, minlength=len(names))
    counts = np.bincount(index, minlength=len(names))
    return {n: float(s / c) for n, s, c in zip(names, sums, counts, strict=True)}


def _hit_fractions(report: ScoreReport) -> dict[str, np.ndarray]:
    """Per metric, ``(G,)``: the fraction of its (variant, threshold) pairs at which each valid GT is matched, and
    ``<metric>@0``: matched at the strictest threshold (the paper's strict figures)."""
    out = {}
    for name, m in report.matches.items():
        hit = m.est_ids >= 0  # (V, K, G)
        out[name] = hit.reshape(-1, hit.shape[-1]).mean(0) if hit.size else np.zeros(hit.shape[-1])
        out[f"{name}@0"] = hit[0, 0].astype(np.float64) if hit.size else np.zeros(hit.shape[-1])
    return out


def objects_bop19(report: ScoreReport) -> list[Group]:
    """Per object (ascending id), its valid GT instances and its AR_VSD, AR_MSSD, AR_MSPD and strict recalls; the
    instance-weighted mean of a column over the objects is the file's score."""
    gts = report.matches["mssd"].gts if "mssd" in report.matches else ()
    objs = [g.obj_id for g in gts]
    fractions = _hit_fractions(report)
    columns = {"AR_VSD": "vsd", "AR_MSSD": "mssd", "AR_MSPD": "mspd", "AR_MSSD<5%": "mssd@0", "AR_MSPD<5px": "mspd@0"}
    means = {col: _mean_by(objs, fractions[k]) if k in fractions else {} for col, k in columns.items()}
    counts = {o: objs.count(o) for o in set(objs)}
    return [Group(str(o), counts[o], {col: means[col].get(o) for col in OBJECT_COLUMNS_BOP19}) for o in sorted(counts)]


def scenes_bop19(report: ScoreReport, scene_of: Mapping[tuple[int, int], str], keys: list[str]) -> list[Group]:
    """Per scene of ``keys`` (``scene_of``: image ``(scene_id, im_id)`` -> scene key), its valid GT instances and its
    AR (module docstring), worst first; scenes without a target last."""
    gts = report.matches["mssd"].gts if "mssd" in report.matches else ()
    scenes = [scene_of[(int(g.scene_id), g.im_id)] for g in gts]
    fractions = _hit_fractions(report)
    metrics = [m for m in ("vsd", "mssd", "mspd") if m in fractions]
    per_gt = np.mean([fractions[m] for m in metrics], axis=0) if gts else np.zeros(0)
    measure = _mean_by(scenes, per_gt)
    strict = _mean_by(scenes, fractions["mssd@0"]) if gts else {}
    groups = [Group(k, scenes.count(k), {"AR_MSSD<5%": strict.get(k)}, measure.get(k)) for k in keys]
    return rank(groups)


def objects_bop24(report: DetectionReport) -> list[Group]:
    """Per object with a visible GT instance (ascending id), its mAP per error type and its recall at the loosest
    MSSD threshold (true positives over its GT instances)."""
    mssd = report.per_type["mssd"]
    out = []
    for o in mssd.objects:
        loosest = mssd.curves[o][-1]
        values: dict[str, float | None] = {
            f"mAP_{name}": s.object_ap.get(o)
            for name, s in report.per_type.items()
            if f"mAP_{name}" in OBJECT_COLUMNS_BOP24
        }
        values["recall_mssd"] = loosest.true_positives / loosest.n_gts if loosest.n_gts else None
        out.append(Group(str(o), loosest.n_gts, values))
    return out


def scenes_bop24(report: DetectionReport, scene_of: Mapping[tuple[int, int], str], keys: list[str]) -> list[Group]:
    """Per scene of ``keys``, its visible GT instances, its true and false positives at the loosest MSSD threshold
    and its recall (module docstring), worst first; scenes without a visible instance last."""
    instances: dict[str, int] = {}
    for scene_id, im_id, _gt, _obj in report.visible_gts:
        key = scene_of[(scene_id, im_id)]
        instances[key] = instances.get(key, 0) + 1
    types = [t for t in ("mssd", "mspd") if t in report.per_type]
    tp = {k: np.zeros(sum(len(report.per_type[t].thresholds) for t in types)) for k in keys}
    fp = dict.fromkeys(keys, 0)
    for r in report.records:
        key = scene_of.get((r.scene_id, r.im_id))
        if key not in tp:
            continue
        tp[key] += np.concatenate([r.status[t] == 1 for t in types])
        fp[key] += int(r.status["mssd"][-1] == 0)
    groups = []
    for k in keys:
        n = instances.get(k, 0)
        recall = float(np.mean(tp[k]) / n) if n else None
        strict = float(tp[k][0] / n) if n else None
        groups.append(Group(k, n, {"recall_mssd<5%": strict, "false_positives": float(fp[k])}, recall))
    return rank(groups)


def rank(groups: list[Group]) -> list[Group]:
    """Worst first: by measure ascending, then key; groups without a measure (nothing to find) last."""
    return sorted(groups, key=lambda g: (g.measure is None, g.measure if g.measure is not None else 0.0, g.key))


def verdicts_bop19(report: ScoreReport) -> Verdicts:
    """Each evaluated row's verdict at the strictest MSSD threshold, and the valid GT instances no row matched there."""
    rows = {r.line: RIGHT if int(r.mssd_match[0]) >= 0 else WRONG for r in report.records if r.line is not None}
    missed: dict[tuple[int, int], set[int]] = {}
    m = report.matches.get("mssd")
    if m is not None:
        for g, est in zip(m.gts, m.est_ids[0, 0] if m.est_ids.size else [], strict=False):
            if est < 0:
                missed.setdefault((int(g.scene_id), g.im_id), set()).add(g.gt_id)
    return Verdicts(rows, missed)


def verdicts_bop24(report: DetectionReport) -> Verdicts:
    """Each evaluated row's verdict at the strictest MSSD threshold (a hit of a GT under 10 % visible: left out),
    and the visible GT instances that are no hit's closest instance there."""
    status = {-1: LEFT_OUT, 0: WRONG, 1: RIGHT}
    rows = {r.line: status[int(r.status["mssd"][0])] for r in report.records if r.line is not None}
    found = {(r.scene_id, r.im_id, r.gt_id) for r in report.records if int(r.status["mssd"][0]) == 1}
    missed: dict[tuple[int, int], set[int]] = {}
    for scene_id, im_id, gt_id, _obj in report.visible_gts:
        if (scene_id, im_id, gt_id) not in found:
            missed.setdefault((scene_id, im_id), set()).add(gt_id)
    return Verdicts(rows, missed)


def error_values(report: ScoreReport | DetectionReport) -> dict[str, np.ndarray]:
    """Per evaluated row, its normalised MSSD (/ diameter) and MSPD (px at 640 wide) against the GT instance it is
    matched to at the loosest MSSD threshold, else its closest (as ``errors_<stem>.csv`` holds them); ``inf``: farther
    than the scorer computes."""
    if isinstance(report, DetectionReport):
        errs = np.array([r.errors[1:] for r in report.records if r.errors is not None], dtype=np.float64).reshape(-1, 2)
        return {"mssd": errs[:, 0], "mspd": errs[:, 1]}
    mssd, mspd = [], []
    for r in report.records:
        matched = int(r.mssd_match[-1])
        j = int(np.flatnonzero(r.gt_ids == matched)[0]) if matched >= 0 else r.best_gt()
        mssd.append(r.mssd[j])
        mspd.append(r.mspd[j])
    return {"mssd": np.asarray(mssd, np.float64), "mspd": np.asarray(mspd, np.float64)}


def thresholds(report: ScoreReport | DetectionReport) -> dict[str, np.ndarray]:
    """The MSSD (fraction of the diameter) and MSPD (px at 640 wide) thresholds of the report's protocol."""
    if isinstance(report, DetectionReport):
        return {"mssd": report.per_type["mssd"].thresholds, "mspd": report.per_type["mspd"].thresholds}
    return {"mssd": report.mssd_thresholds, "mspd": report.mspd_thresholds}
