"""The report page as HTML text: one self-contained file (inline style, no script, no font or file from the network)
whose images are files of its own folder, named relative to it, so that it opens from disk anywhere it is copied.

Every text that comes from a file (method names, scene keys, failure reasons, the sidecar) goes through
:func:`html.escape`; nothing here reads a file.
"""

from __future__ import annotations

import html
import json
from collections.abc import Sequence
from dataclasses import dataclass

from bop_cender.report.breakdown import OBJECT_COLUMNS_BOP19, OBJECT_COLUMNS_BOP24
from bop_cender.report.page_data import PageData

STYLE = """
body { font: 14px/1.45 system-ui, sans-serif; margin: 1.5em auto; max-width: 1200px; padding: 0 1em; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 2em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 0.5em 0; } td, th { padding: 2px 8px; border-bottom: 1px solid #eee; }
th { text-align: left; background: #f4f4f4; } td.num { text-align: right; font-variant-numeric: tabular-nums; }
tr.run td { font-weight: 600; } .note { color: #555; font-size: 0.92em; }
figure { margin: 1em 0; } figure img { max-width: 100%; border: 1px solid #ddd; }
.plots img { width: 48%; min-width: 320px; } pre { background: #f7f7f7; padding: 0.6em; overflow-x: auto; }
.bad { color: #b00; }
"""


@dataclass(frozen=True)
class SceneFigure:
    """A scene's figure in the page's folder: its path relative to ``index.html`` and who made it."""

    path: str
    source: str


def number(value: float | None, digits: int = 3) -> str:
    """A score as the page shows it: fixed digits, ``n/a`` where not available."""
    return "n/a" if value is None else f"{value:.{digits}f}"


def table(header: Sequence[str], rows: Sequence[Sequence[str]], classes: Sequence[str] | None = None) -> str:
    """An HTML table of already escaped cells; a cell that starts with a digit, ``-`` or ``n/a`` is right-aligned."""

    def cell(c: str) -> str:
        numeric = c[:1].isdigit() or c.startswith(("-", "n/a"))
        return f'<td class="num">{c}</td>' if numeric else f"<td>{c}</td>"

    head = "".join(f"<th>{h}</th>" for h in header)
    opening = [f'<tr class="{classes[i]}">' if classes and classes[i] else "<tr>" for i in range(len(rows))]
    body = "".join(o + "".join(cell(c) for c in r) + "</tr>" for o, r in zip(opening, rows, strict=True))
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def render_page(
    data: PageData, plots: dict[str, str], plot_notes: dict[str, str], figures: dict[str, SceneFigure], shown: int
) -> str:
    """The page of ``data`` (see the module docstring).

    Args:
        plots: error name -> the plot's path relative to the page. plot_notes: error name -> the line under it.
        figures: scene key -> its figure. shown: how many scenes have a figure (the worst ones).
    """
    e = html.escape
    meta_ds = data.dataset
    method = data.score_rows[0].method
    title = f"{method} on {meta_ds.name} {meta_ds.split}"
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="generator" content="bop-cender report">',
        f"<title>{e(title)}</title><style>{STYLE}</style></head><body>",
        f"<h1>{e(title)}</h1>",
        f'<p class="note">results {e(str(data.results))}; run sidecar '
        + (e(str(data.results.with_suffix(".json").name)) if data.sidecar is not None else "none (scored with the"
           " data options given)")
        + f"; protocol {e(_protocol_name(data.protocol))}</p>",
        _scores_section(data),
        _objects_section(data),
        _plots_section(plots, plot_notes),
        _scenes_section(data, figures, shown),
        _failed_section(data),
        _timings_section(data),
        _config_section(data),
        "</body></html>",
    ]  # fmt: skip
    return "\n".join(parts) + "\n"


def _protocol_name(protocol: str) -> str:
    return "BOP'24/'25 6D detection (mAP)" if protocol == "bop24" else "BOP'19 6D localisation (AR)"


def _scores_section(data: PageData) -> str:
    e = html.escape
    keys = data.score_keys
    rows = [[e(r.method), e(r.source)] + [number(r.scores.get(k)) for k in keys] for r in data.score_rows]
    classes = ["run"] + [""] * (len(rows) - 1)
    note = (
        "The paper reports no BOP'24 figure: no reference row."
        if data.protocol == "bop24"
        else "Rows marked [reported]: the CenDerNet paper's tables (bop_cender/report/paper_tables.csv); n/a where it"
        " reports no such figure, or without test depth (VSD and AR)."
        if len(rows) > 1
        else "The paper reports no figure for this dataset and split."
    )
    lines = "".join(f"<li>{e(line)}</li>" for line in data.summary)
    return (
        '<h2 id="scores">Scores</h2>'
        + table(["method", "source", *map(e, keys)], rows, classes)
        + f'<p class="note">{e(note)}</p><ul class="note">{lines}</ul>'
    )


def _objects_section(data: PageData) -> str:
    e = html.escape
    columns = OBJECT_COLUMNS_BOP24 if data.protocol == "bop24" else OBJECT_COLUMNS_BOP19
    rows = [[e(g.key), str(g.instances)] + [number(g.values.get(c)) for c in columns] for g in data.objects]
    what = (
        "GT instances at least 10 % visible; mAP per error type; recall_mssd: true positives at the loosest MSSD"
        " threshold over the instances"
        if data.protocol == "bop24"
        else "valid target instances; recall averaged over each metric's thresholds (AR_*) and at the strictest"
        " (5 % of the diameter, 5 px); the instance-weighted mean over the objects is the file's score"
    )
    return (
        '<h2 id="objects">Per object</h2>'
        + table(["object", "instances", *map(e, columns)], rows)
        + f'<p class="note">{e(what)}</p>'
    )


def _plots_section(plots: dict[str, str], notes: dict[str, str]) -> str:
    e = html.escape
    images = "".join(
        f'<img src="{e(path)}" alt="{e(name)} errors against the thresholds">' for name, path in plots.items()
    )
    lines = "".join(f"<li>{e(notes[name])}</li>" for name in plots if name in notes)
    return (
        '<h2 id="errors">MSSD and MSPD against the thresholds</h2>'
        f'<div class="plots">{images}</div><ul class="note">{lines}</ul>'
        '<p class="note">Each evaluated row\'s error against the GT instance it is matched to at the loosest MSSD'
        " threshold, else its closest (as the scorer's errors CSV holds them).</p>"
    )


def _measure_note(data: PageData) -> str:
    if data.protocol == "bop24":
        return (
            "measure: the scene's recall, true positives over its GT instances at least 10 % visible, averaged over"
            " the MSSD and MSPD thresholds; false positives at the loosest MSSD threshold"
        )
    return (
        "measure: the scene's AR, whether each valid target instance is matched, averaged over the instances and over"
        " the thresholds of MSSD, MSPD (and VSD with test depth)"
    )


def _scenes_section(data: PageData, figures: dict[str, SceneFigure], shown: int) -> str:
    e = html.escape
    scene_times = data.run_timings.get("scenes", {})
    strict = "recall_mssd<5%" if data.protocol == "bop24" else "AR_MSSD<5%"
    extra_col = ["false positives"] if data.protocol == "bop24" else []
    rows = []
    for rank, g in enumerate(data.scenes, start=1):
        state = '<span class="bad">failed</span>' if g.key in data.failed else ""
        times = scene_times.get(g.key)
        link = f'<a href="#scene-{e(g.key)}">{e(g.key)}</a>' if g.key in figures else e(g.key)
        rows.append(
            [str(rank), link, number(g.measure), number(g.values.get(strict)), str(g.instances)]
            + ([str(int(g.values.get("false_positives") or 0))] if extra_col else [])
            + ["n/a" if times is None else f"{sum(times.values()):.1f}", state]
        )
    head = ["rank", "scene", "measure", e(strict), "instances", *extra_col, "run s", ""]
    figs = []
    for g in data.scenes:
        fig = figures.get(g.key)
        if fig is None:
            continue
        figs.append(
            f'<figure id="scene-{e(g.key)}"><img src="{e(fig.path)}" alt="scene {e(g.key)}">'
            f"<figcaption>scene {e(g.key)}: measure {number(g.measure)}, {g.instances} instances; figure"
            f" {e(fig.source)}</figcaption></figure>"
        )
    legend = (
        "Outlines: green a pose within the strictest MSSD threshold (5 % of the object's diameter), red one that is"
        " not, cyan a GT part no pose matched (yellow: left out, or a run figure of a scene without GT)."
    )
    more = "" if shown >= len(data.scenes) else f" Figures of the {shown} worst scenes (--max-figures)."
    return (
        f'<h2 id="scenes">Scenes, worst first ({len(data.scenes)})</h2>'
        + table(head, rows)
        + f'<p class="note">{e(_measure_note(data))}; run s: the run\'s seconds on the scene (its sidecar).</p>'
        + f'<p class="note">{e(legend + more)}</p>'
        + "".join(figs)
    )


def _failed_section(data: PageData) -> str:
    e = html.escape
    if not data.failed:
        said = "None." if data.sidecar is not None else "None recorded (no run sidecar)."
        return f'<h2 id="failed">Failed scenes</h2><p>{said}</p>'
    rows = [[e(k), e(str(v))] for k, v in data.failed.items()]
    return (
        f'<h2 id="failed">Failed scenes ({len(rows)})</h2>'
        + table(["scene", "why"], rows)
        + '<p class="note">Their targets count as misses; <code>bop-cender run --resume</code> redoes only them.</p>'
    )


def _timings_section(data: PageData) -> str:
    e = html.escape
    t = data.run_timings
    parts = ['<h2 id="timings">Timings</h2>']
    if t:
        rows = [[e(stage), f"{seconds:.1f}"] for stage, seconds in t.get("stages", {}).items()]
        if "wall" in t:
            rows.append(["run wall time", f"{t['wall']:.1f}"])
        parts.append(table(["run stage", "seconds (all scenes)"], rows))
    else:
        why = (
            "no run sidecar"
            if data.sidecar is None
            else "the run recorded none (--deterministic-time, or an older run)"
        )
        parts.append(f"<p>Run stages: not recorded ({e(why)}).</p>")
    scoring = data.scored.report.timings
    parts.append(table(["scoring step", "seconds"], [[e(k), f"{v:.1f}"] for k, v in scoring.items()]))
    return "".join(parts)


def _config_section(data: PageData) -> str:
    e = html.escape
    if data.sidecar is None:
        return (
            '<h2 id="config">Configuration and data</h2><p>No run sidecar beside the results: the settings that made'
            f" them are unknown. Scored on {e(str(data.dataset.root))} ({e(data.scored.choice.origin)}).</p>"
        )
    shown = {k: v for k, v in data.sidecar.items() if k != "extra"}
    extra = {k: v for k, v in data.sidecar.get("extra", {}).items() if k != "timings"}
    return (
        '<h2 id="config">Configuration and data</h2>'
        f"<p>From the run sidecar {e(data.results.with_suffix('.json').name)}.</p>"
        f"<pre>{e(json.dumps({**shown, 'extra': extra}, indent=1))}</pre>"
    )
