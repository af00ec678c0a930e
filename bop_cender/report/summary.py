"""What ``bop-cender score`` prints: the AR table of one or more methods and the lines under it."""

from __future__ import annotations

from bop_cender.eval.score_report import SCORE_KEYS, ScoreReport


def format_scores(rows: list[tuple[str, dict[str, float | None]]], digits: int = 3) -> str:
    """A plain-text table, one row per (name, scores), one column per score; ``n/a`` where None."""
    header = ["method", *SCORE_KEYS]
    body = [[name] + [_fmt(s.get(k), digits) for k in SCORE_KEYS] for name, s in rows]
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
    return lines + [f"note: {n}" for n in report.notes]


def _fmt(value: float | None, digits: int) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"
