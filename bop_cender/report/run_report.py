"""``bop-cender report``: one static page of a run, a folder with ``index.html``, its plots and its scenes' figures.

The folder is built whole in a temporary folder beside the target and renamed into place only when every file is
written: a failure leaves nothing half-written, and a previous report there stands until the new one replaces it. A
folder that is neither empty nor a report (no ``report.json`` of ours) is never replaced: ``--out .`` must not
delete a working directory.
"""

from __future__ import annotations

import json
import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bop_cender.data.bop_io import check_output_dir, load_rgb
from bop_cender.errors import BopCenderError, ConfigError
from bop_cender.eval.score_file import ScoredFile
from bop_cender.meshes import MeshCache
from bop_cender.report.breakdown import error_values, thresholds
from bop_cender.report.error_plots import error_plot, share_within
from bop_cender.report.estimate_figure import estimate_figure, scene_panels
from bop_cender.report.html_page import SceneFigure, number, render_page
from bop_cender.report.page_data import PageData, collect_page

#: ``report.json``'s ``format``: marks a folder this command may replace.
REPORT_FORMAT = "bop-cender-report"
#: Scenes with a figure by default: the worst ones (a page of a 1000-group T-LESS split stays light).
DEFAULT_MAX_FIGURES = 100
#: Who made a figure, as the page says it.
FROM_RUN = "made by the run (run --vis: views, heatmaps, centres, outlines)"
DRAWN_HERE = "drawn by the report from the results rows and the images (no network re-run)"


@dataclass(frozen=True)
class WrittenReport:
    """What :func:`write_report` wrote: the folder, its page, and how many scene figures came from where."""

    folder: Path
    index: Path
    from_run: int
    drawn: int
    scenes: int


def default_report_dir(results: str | Path) -> Path:
    """``<csv folder>/<stem>_report``: beside the results, named for them."""
    results = Path(results)
    return results.with_name(results.name.split(".")[0] + "_report")


def figure_name(scene_key: str) -> str:
    """The file name of a scene's figure: the one ``run --vis`` writes (its shard's name, ``/`` as ``__``)."""
    return re.sub(r"[^A-Za-z0-9_.-]", "__", scene_key) + ".png"


def check_report_dir(out: Path) -> Path:
    """``out`` if a report may be written there: not a file (nor below one), and empty or an earlier report.

    Raises:
        ConfigError: naming ``--out``.
    """
    check_output_dir(out)
    if out.is_dir() and any(out.iterdir()) and not _is_report(out):
        raise ConfigError(
            "exists and is not a bop-cender report (no report.json of ours); give a new or empty folder",
            file=out,
            field="--out",
        )
    return out


def _is_report(folder: Path) -> bool:
    try:
        return json.loads((folder / "report.json").read_text(encoding="utf-8")).get("format") == REPORT_FORMAT
    except (OSError, ValueError, AttributeError):
        return False


def write_report(
    results: str | Path,
    out: str | Path | None = None,
    *,
    vis_dir: str | Path | None = None,
    max_figures: int = DEFAULT_MAX_FIGURES,
    progress: bool = False,
    scored: ScoredFile | None = None,
    **data_options: Any,
) -> WrittenReport:
    """Score ``results`` (as ``bop-cender score``), gather the page and write its folder ``out`` (default
    :func:`default_report_dir`), replacing an earlier report there.

    Args:
        vis_dir: the run's ``--vis`` figures (default: the folder its sidecar names, where it still exists); a scene
            without one there gets a figure drawn from its rows (:mod:`bop_cender.report.estimate_figure`).
        max_figures: figures of at most this many scenes, the worst first (every scene stays in the table).
        data_options: where the data are and how to score, as :func:`~bop_cender.report.page_data.collect_page`
            takes them (``dataset``, ``data_root``, ``split``, ``n_views``, ``seed``, ``model_type``, ``vsd_delta``,
            ``protocol``, ``open_data``): ``score``'s options. ``scored``: the file already scored (``run --score
            --report``): not scored again.

    Raises:
        ConfigError: ``out`` is a file or a folder that is not a report; the data cannot be told.
        ResultsError: the CSV or its sidecar is missing or malformed, or names unknown scenes, images or objects.
    """
    results = Path(results)
    folder = check_report_dir(Path(out) if out is not None else default_report_dir(results))
    if max_figures < 0:
        raise ConfigError(f"expected a number of scenes >= 0, got {max_figures}", field="--max-figures")
    data = collect_page(results, progress=progress, scored=scored, **data_options)
    vis = Path(vis_dir) if vis_dir is not None else _sidecar_vis_dir(data)
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
    try:
        plots, notes = _plots(data, tmp)
        figures = _figures(data, tmp, vis, max_figures)
        shown = min(max_figures, len(data.scenes))
        (tmp / "index.html").write_text(render_page(data, plots, notes, figures, shown), encoding="utf-8")
        (tmp / "report.json").write_text(json.dumps(_summary_json(data, figures), indent=1) + "\n", encoding="utf-8")
        tmp.chmod(0o755)
        _swap_into_place(tmp, folder)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    from_run = sum(f.source == FROM_RUN for f in figures.values())
    return WrittenReport(folder, folder / "index.html", from_run, len(figures) - from_run, len(data.scenes))


def _sidecar_vis_dir(data: PageData) -> Path | None:
    named = (data.sidecar or {}).get("extra", {}).get("vis_dir")
    return Path(named) if isinstance(named, str) and Path(named).is_dir() else None


def _plots(data: PageData, folder: Path) -> tuple[dict[str, str], dict[str, str]]:
    """The two error plots in ``folder/plots`` (paths relative to the page) and the line under each."""
    values, ths = error_values(data.scored.report), thresholds(data.scored.report)
    plots, notes = {}, {}
    for name in ("mssd", "mspd"):
        rel = f"plots/{name}.png"
        error_plot(name, values[name], ths[name], folder / rel)
        plots[name] = rel
        strict, loose = float(ths[name][0]), float(ths[name][-1])
        notes[name] = (
            f"{name.upper()}: {number(share_within(values[name], strict))} of the {len(values[name])} evaluated rows"
            f" under the strictest threshold ({strict:g}), {number(share_within(values[name], loose))} under the"
            f" loosest ({loose:g})"
        )
    return plots, notes


def _figures(data: PageData, folder: Path, vis: Path | None, max_figures: int) -> dict[str, SceneFigure]:
    """The figures of the ``max_figures`` worst scenes in ``folder/scenes``: the run's where it made them, else drawn."""
    by_image = data.rows_by_image()
    meshes: MeshCache | None = None
    figures = {}
    for g in data.scenes[:max_figures]:
        name = figure_name(g.key)
        target = folder / "scenes" / name
        target.parent.mkdir(parents=True, exist_ok=True)
        if vis is not None and (vis / name).is_file():
            shutil.copyfile(vis / name, target)
            figures[g.key] = SceneFigure(f"scenes/{name}", FROM_RUN)
            continue
        if meshes is None:
            meshes = MeshCache(data.dataset.eval_models or data.dataset.models)
        panels = scene_panels(
            data.scene_images(g.key), by_image, data.verdicts.rows, data.verdicts.missed, data.rgb_paths, _read_rgb
        )
        title = f"scene {g.key}: measure {number(g.measure)}" + (
            " (the run failed on it)" if g.key in data.failed else ""
        )
        estimate_figure(g.key, panels, meshes, title, target)
        figures[g.key] = SceneFigure(f"scenes/{name}", DRAWN_HERE)
    return figures


def _read_rgb(path: Path) -> np.ndarray | None:
    """An image's pixels, None where it cannot be read (the panel is drawn black, the outlines still say the verdict)."""
    try:
        return load_rgb(path) if Path(path).is_file() else None
    except BopCenderError:
        return None


def _summary_json(data: PageData, figures: dict[str, SceneFigure]) -> dict:
    """``report.json``: what the page shows, for scripts (and the mark that the folder is a report)."""
    return {
        "format": REPORT_FORMAT,
        "results": str(data.results),
        "protocol": data.protocol,
        "scores": [{"method": r.method, "source": r.source, **r.scores} for r in data.score_rows],
        "objects": [{"object": g.key, "instances": g.instances, **g.values} for g in data.objects],
        "scenes": [
            {
                "scene": g.key,
                "measure": g.measure,
                "instances": g.instances,
                **g.values,
                "figure": figures[g.key].path if g.key in figures else None,
                "figure_source": figures[g.key].source if g.key in figures else None,
            }
            for g in data.scenes
        ],  # fmt: skip
        "failed_scenes": data.failed,
        "run_timings": data.run_timings,
    }


def _swap_into_place(new: Path, folder: Path) -> None:
    """Rename the finished ``new`` folder onto ``folder``; an earlier report there is moved aside first and removed
    once the new one is in place (put back if the rename fails)."""
    old = None
    if folder.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{folder.name}.old.", dir=folder.parent))
        old.rmdir()
        folder.rename(old)
    try:
        new.rename(folder)
    except OSError:
        if old is not None:
            old.rename(folder)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
