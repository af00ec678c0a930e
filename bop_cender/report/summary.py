"""What ``bop-cender score`` prints: the AR (BOP'19) or mAP (BOP'24) table of one or more methods and the lines
under it."""

from __future__ import annotations

from bop_cender.eval.detection import BOP24_KEYS
from bop_cender.eval.score_report import SCORE_KEYS, ScoreCounts, ScoreReport

#: The BOP'24 keys a table shows (the time per image is said under it).
MAP_KEYS = tuple(k for k in BOP24_KEYS if k != "bop24_average_time_per_image")


def format_scores(
    rows: list[tuple[str, dict[str, float | None]]], digits: int = 3, keys: tuple[str, ...] = SCORE_KEYS
) -> str:
    """A plain-text table, one row per (name, scores), one column per score of ``keys`` (BOP'19's AR keys, or
    :data:`MAP_KEYS`); ``n/a`` where None."""
    header = ["method", *keys]
    body = [[name] + [_fmt(s.get(k), digits) for k in keys] for name, s in rows]
    widths = [max(len(r[i]) for r in [header, *body]) for i in range(len(header))]
    lines = ["  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths, strict=True)))
             for r in [header, *body]]  # fmt: skip
    return "\n".join(lines)


def summary_lines(report: ScoreReport) -> list[str]:
    """Metadata lines printed under the AR table."""
    m = report.metadata
    lines = [
        f"dataset {m.dataset} split {m.split} ({m.root})",
        f"targets: {m.targets_note}",
        f"estimates: {m.counts.rows} rows, {m.counts.evaluated} evaluated (top-n per target),"
        f" {m.counts.not_target} for non-target images/objects ignored, {m.counts.beyond_top_n} beyond"
        " the top-n cut",
        f"MSPD width {m.mspd_width} px ({m.mspd_width_source}); VSD delta "
        + ("n/a" if m.vsd_delta is None else f"{m.vsd_delta:g} mm ({m.vsd_delta_source})"),
        "time per image: " + ("n/a (a row has time < 0)" if m.time_per_image is None else f"{m.time_per_image:.3f} s"),
    ]
    return lines + why_lines(report) + [f"note: {n}" for n in report.notes]


def why_lines(report: ScoreReport) -> list[str]:
    """Why the recall is below 1, per cause with counts (none when every target instance is matched).

    Said because the reasons are surprising but correct: ground-truth poses score below 1 where an
    instance too little visible to be a target takes a target's top-n place (equal scores keep file
    order), and a user would otherwise take the scorer for broken.
    """
    c = report.metadata.counts
    causes = (c.unmatched_not_visible, c.unmatched_duplicate, c.unmatched_far)
    if not c.missed_instances and not any(causes):
        return []
    head = (
        f"why not 1 (MSSD, loosest threshold): {c.missed_instances} of {c.target_instances} target instances"
        " matched by no estimate; "
    )
    if not any(causes):  # no cause to list: say so, not a colon before nothing
        head += f"each of the {c.evaluated} evaluated estimates matches an instance (the missed ones have no estimate)"
        return [head] + _beyond_top_n(c)
    lines = [head + f"{sum(causes)} of {c.evaluated} evaluated estimates match none:"]
    if c.unmatched_not_visible:
        lines.append(
            f"  {c.unmatched_not_visible} closest to an instance that is not a target (too little of it visible,"
            " under 10 %, or beyond its image's inst_count most visible)"
        )
    if c.unmatched_duplicate:
        lines.append(f"  {c.unmatched_duplicate} duplicates: their instance was matched by a higher-ranked estimate")
    if c.unmatched_far:
        lines.append(f"  {c.unmatched_far} farther from every instance than the loosest threshold")
    return lines + _beyond_top_n(c)


def _beyond_top_n(c: ScoreCounts) -> list[str]:
    """The closing line on the rows the top-n cut left unevaluated (none where it left none)."""
    if not c.beyond_top_n:
        return []
    return [
        f"  and {c.beyond_top_n} rows beyond the top-n cut were not evaluated (a target keeps its inst_count"
        " highest-scored estimates; equal scores keep file order)"
    ]


def _fmt(value: float | None, digits: int) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"
