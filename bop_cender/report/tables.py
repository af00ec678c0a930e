"""Comparison tables: one row per method, from results CSVs (scored here), scores JSONs, and the paper.

Inputs, any mix:

- a BOP results CSV (ours, CosyPose's published files such as
  ``cosypose114533-eccv2020_tless-test-primesense.csv``, PVNet outputs converted by
  :mod:`bop_cender.results.convert_pvnet`): scored with :func:`bop_cender.eval.score_file.score_file`
  (its scores JSON and errors CSV are written too);
- a ``scores_*.json`` already written by ``bop-cender score``;
- ``reference="paper"``: the numbers the CenDerNet paper reports, from the package's ``paper_tables.csv`` (``results/reference/``),
  filtered to the table's dataset and split (one row per method, its tables merged).

Outputs: a markdown table (returned and written), a CSV and a bar chart PNG (matplotlib, Agg) of the scores.
A table holds one dataset and split (inputs of several are refused before anything is scored), each row
has a name of its own (two results of one method are told apart by their files), and nothing is written
unless every input was read and scored.
"""

from __future__ import annotations

import csv
import io
import warnings
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

from bop_cender.data.bop_io import check_output_dir, check_output_file, require_file, write_text_atomic
from bop_cender.data.registry import DatasetRequest, open_dataset
from bop_cender.data.types import Dataset
from bop_cender.errors import ConfigError, ResultsError, ResultsWarning
from bop_cender.eval.detection_file import detection_file_outputs
from bop_cender.eval.detection_report import read_detection_scores_json
from bop_cender.eval.score_file import (
    ScoredFile,
    choose_data,
    method_name,
    score_file,
    score_file_outputs,
    write_scored,
)
from bop_cender.eval.score_report import SCORE_KEYS, read_scores_json
from bop_cender.report.png import pyplot, save_png
from bop_cender.report.reference_table import (  # noqa: F401  (re-exported: the tables' one import site)
    PAPER_TABLES,
    REFERENCE_COLUMNS,
    MethodRow,
    read_reference_table,
    reference_rows,
    reference_rows_of,
)
from bop_cender.report.summary import MAP_KEYS
from bop_cender.results.files import parse_result_filename


@dataclass
class Comparison:
    """A comparison table and the files it was written to."""

    rows: list[MethodRow]
    dataset: str | None
    split: str | None
    files: dict[str, Path] = field(default_factory=dict)
    scores: dict[Path, Path] = field(default_factory=dict)  # each CSV input's scores JSON, as written
    protocol: str = "bop19"

    @property
    def keys(self) -> tuple[str, ...]:
        """The table's columns: BOP'19's six AR scores, or BOP'24's six mAP scores."""
        return MAP_KEYS if self.protocol == "bop24" else SCORE_KEYS

    @property
    def title(self) -> str:
        what = "BOP'24/'25 detection scores (mAP)" if self.protocol == "bop24" else "BOP'19 scores"
        return f"{what}, {self.dataset or '?'} {self.split or '?'}"

    def markdown(self, digits: int = 3) -> str:
        """The table in markdown: method, source, then the six scores (``–`` where not available)."""
        head = ["method", "source", *self.keys]
        lines = [f"### {self.title}", "", "| " + " | ".join(head) + " |",
                 "|" + "|".join(["---"] * 2 + ["---:"] * len(self.keys)) + "|"]  # fmt: skip
        for r in self.rows:
            cells = [r.method, r.source] + [
                "–" if r.scores.get(k) is None else f"{r.scores[k]:.{digits}f}" for k in self.keys
            ]
            lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
        return "\n".join(lines) + "\n"

    def csv_text(self) -> str:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["method", "source", "dataset", "split", "protocol", *self.keys])
        for r in self.rows:
            w.writerow(
                [r.method, r.source, r.dataset or "", r.split or "", self.protocol]
                + ["" if r.scores.get(k) is None else repr(r.scores[k]) for k in self.keys]
            )
        return buf.getvalue()


def _cell(text: str) -> str:
    """A markdown table cell: one line (a name with a line break would end the row), pipes shown as slashes."""
    return " ".join(text.split()).replace("|", "/")


def compare(
    inputs: list[str | Path],
    *,
    reference: str | None = None,
    dataset: str | None = None,
    data_root: str | Path | None = None,
    split: str | None = None,
    n_views: int | None = None,
    seed: int | None = None,
    model_type: str | None = None,
    vsd_delta: float | None = None,
    out_dir: str | Path = ".",
    progress: bool = True,
    open_data: Callable[[DatasetRequest], Dataset] = open_dataset,
    protocol: str | None = None,
) -> Comparison:
    """Build, write and return the comparison of ``inputs`` (see the module docstring).

    Nothing is written unless everything succeeds: every input, its dataset and split and the reference
    table are checked before any input is scored, and the scores of the CSV inputs are written with the
    table once all are scored. A table holds one dataset and split (inputs of several are refused), and
    each row has a name of its own (a method given twice is told apart by its file).

    Args:
        inputs: results CSVs and/or scores JSONs, one row each, in this order.
        reference: ``"paper"`` (or a CSV in the paper tables' format) to add reference rows.
        dataset, data_root, split, n_views, seed, model_type, vsd_delta, open_data: passed to the scoring of CSV inputs
            (:func:`~bop_cender.eval.score_file.score_file`) (default: their
            file names / sidecars, the toolkit's delta).
        out_dir: where the scores of CSV inputs and the comparison files are written.
        protocol: ``bop19`` (AR) or ``bop24`` (mAP) for every input; None: each CSV's sidecar's, each JSON's own.
            A table holds one protocol (inputs of two are refused) and says which.

    Raises:
        ConfigError: an input is neither ``.csv`` nor ``.json`` or is given twice, the inputs are for several
            datasets or splits, the reference table is missing or malformed, or ``out_dir`` is a file.
        ResultsError: an input is missing, a directory or malformed (or cannot be scored).
    """
    out_dir = check_output_dir(out_dir)
    paths = _check_inputs(inputs)
    table = None
    if reference is not None:
        table = read_reference_table(PAPER_TABLES if reference == "paper" else Path(reference))
    planned: dict[Path, tuple[str | None, str | None]] = {}
    jsons: dict[Path, dict] = {}
    protocols: dict[Path, str] = {}
    for path in paths:
        if path.suffix == ".csv":
            choice = choose_data(
                path, dataset=dataset, data_root=data_root, split=split, n_views=n_views, seed=seed,
                model_type=model_type,
            )  # fmt: skip
            request = choice.request
            known = request.dataset != "bop"  # named after its folder: told only once it is opened
            planned[path] = (request.dataset, request.split_name) if known else (None, None)
            protocols[path] = protocol or choice.protocol or "bop19"
        else:
            jsons[path] = _read_scores(path)
            planned[path] = _json_dataset_and_split(path, jsons[path])
            protocols[path] = jsons[path].get("protocol", "bop19")
    table_protocol = _one_protocol(protocols, protocol)
    _one_dataset_and_split(planned)  # before anything is scored
    score_dirs = _score_dirs(paths, out_dir, table_protocol)
    outputs = [out for path, folder in score_dirs.items() for out in _outputs(path, folder, table_protocol)]
    known = next(((ds, sp) for ds, sp in planned.values() if ds is not None and sp is not None), None)
    if known is not None:  # the table's files too (a BOP dataset's split is told once it is opened: checked then)
        outputs += _comparison_files(out_dir, *known, table_protocol).values()
    _check_outputs(paths, outputs)
    rows: list[MethodRow] = []
    scored_files: list[ScoredFile] = []
    scores_paths: dict[Path, Path] = {}
    for path in paths:
        if path.suffix == ".csv":
            scored = score_file(
                path, dataset=dataset, data_root=data_root, split=split, n_views=n_views, seed=seed,
                model_type=model_type, vsd_delta=vsd_delta, out_dir=score_dirs[path], progress=progress,
                open_data=open_data, write=False, protocol=table_protocol,
            )  # fmt: skip
            scored_files.append(scored)
            scores_paths[path] = scored.scores_path
            meta = scored.report if table_protocol == "bop24" else scored.report.metadata
            rows.append(
                MethodRow(method_name(path), f"scored {path.name}", scored.report.scores, meta.dataset, meta.split)
            )
        else:
            data = jsons[path]
            meta = data.get("metadata") or {}
            scores = {k: data[k] for k in (MAP_KEYS if table_protocol == "bop24" else SCORE_KEYS)}
            rows.append(
                MethodRow(meta.get("method") or method_name(path), f"scores {path.name}", scores, *planned[path])
            )
    _one_dataset_and_split({path: (r.dataset, r.split) for path, r in zip(paths, rows, strict=True)})
    rows = _named_apart(rows, paths)
    table_dataset = next((r.dataset for r in rows if r.dataset), None if dataset == "bop" else dataset)
    table_split = next((r.split for r in rows if r.split), split)
    if table is not None and table_protocol == "bop24":
        warnings.warn(
            f"the reference table {reference} holds BOP'19 scores only (the paper reports no mAP): a BOP'24 table holds"
            " the inputs alone",
            ResultsWarning,
            stacklevel=2,
        )
    elif table is not None:
        reported = reference_rows_of(table, table_dataset, table_split)
        if not reported:  # asked for and absent: said, not left to be noticed
            warnings.warn(
                f"the reference table {reference} has no row for {table_dataset or 'any dataset'}"
                f" {table_split or 'any split'}: the table holds the inputs alone",
                ResultsWarning,
                stacklevel=2,
            )
        rows += reported
    comparison = Comparison(rows, table_dataset, table_split, scores=scores_paths, protocol=table_protocol)
    comparison.files = _comparison_files(out_dir, table_dataset, table_split, table_protocol)
    _check_outputs(paths, list(comparison.files.values()))
    for scored in scored_files:  # every input scored: now the files
        write_scored(scored)
    write_text_atomic(comparison.files["markdown"], comparison.markdown())
    write_text_atomic(comparison.files["csv"], comparison.csv_text())
    bar_chart(comparison, comparison.files["png"])
    return comparison


def _comparison_files(
    out_dir: Path, dataset: str | None, split: str | None, protocol: str = "bop19"
) -> dict[str, Path]:
    """The table's files (markdown, CSV, bar chart) for a dataset and split (unknown: ``results``, ``all``); a BOP'24
    table's names end in ``_bop24`` (both protocols' tables of one split can sit side by side)."""
    stem = f"comparison_{dataset or 'results'}-{split or 'all'}" + ("_bop24" if protocol == "bop24" else "")
    return {"markdown": out_dir / f"{stem}.md", "csv": out_dir / f"{stem}.csv", "png": out_dir / f"{stem}.png"}


def _json_dataset_and_split(path: Path, data: dict) -> tuple[str | None, str | None]:
    """The dataset and split a scores JSON is for: its ``metadata``, else its file name where that is a BOP result
    name (``scores_{method}_{dataset}-{split}...json``, a DIMO or T-LESS one: a BOP dataset's split is told only once
    its folder is opened), else unknown (the JSON then fits any table). Without the name a bare JSON named for T-LESS
    went into a DIMO table."""
    meta = data.get("metadata") or {}
    if meta.get("dataset") is not None or meta.get("split") is not None:
        return meta.get("dataset"), meta.get("split")
    name = path.name.removeprefix("scores_")
    try:
        parsed = parse_result_filename(name)
    except ResultsError:
        return None, None
    if parsed.dataset not in ("dimo", "tless"):
        return None, None
    return parsed.dataset, DatasetRequest(parsed.dataset, split=parsed.split, split_type=parsed.split_type).split_name


def _read_scores(path: Path) -> dict:
    """A scores JSON of either protocol (a BOP'24 one says ``"protocol": "bop24"``)."""
    from bop_cender.data.bop_io import load_json

    data = load_json(path, error=ResultsError)
    if isinstance(data, dict) and data.get("protocol") == "bop24":
        return read_detection_scores_json(path)
    return read_scores_json(path)


def _one_protocol(protocols: dict[Path, str], asked: str | None) -> str:
    """The table's protocol: every input's (one table, one protocol), else a ConfigError naming the inputs."""
    groups: dict[str, list[str]] = {}
    for path, p in protocols.items():
        groups.setdefault(p, []).append(path.name)
    if len(groups) > 1:
        listed = "; ".join(f"{', '.join(names)}: {p}" for p, names in groups.items())
        raise ConfigError(f"a table holds one protocol, and the inputs are scored under {len(groups)}: {listed}"
                          " (give --protocol to score every CSV under one, or compare them apart)", field="inputs")  # fmt: skip
    return next(iter(groups), asked or "bop19")


def _outputs(path: Path, folder: Path, protocol: str) -> tuple[Path, Path]:
    return detection_file_outputs(path, folder) if protocol == "bop24" else score_file_outputs(path, folder)


def _score_dirs(paths: list[Path], out_dir: Path, protocol: str = "bop19") -> dict[Path, Path]:
    """Where each CSV input's scores and errors files go: ``out_dir``, or, where two CSVs would write the same files
    there (one file name from different folders; their rows named apart by path), ``out_dir/input<k>/`` (k: the
    input's position, from 1)."""
    csvs = [p for p in paths if p.suffix == ".csv"]
    writers = Counter(_outputs(p, out_dir, protocol) for p in csvs)
    return {p: out_dir / f"input{paths.index(p) + 1}" if writers[_outputs(p, out_dir, protocol)] > 1 else out_dir
            for p in csvs}  # fmt: skip


def _check_outputs(inputs: list[Path], outputs: list[Path]) -> None:
    """Refuse outputs that would overwrite an input (``scores_X.json`` given as an input beside ``X.csv``, scored
    into the same folder) or each other (one file would be lost without a word), or that cannot be written (a
    directory there: found only after the first files were written, it left half a comparison behind)."""
    given = {p.resolve(): p for p in inputs}
    seen: dict[Path, Path] = {}
    for out in outputs:
        check_output_file(out, field="--out")
        resolved = out.resolve()
        if resolved in given:
            raise ConfigError(
                f"{out} would be written over the input {given[resolved]}: give another --out folder", field="--out"
            )
        if resolved in seen:
            raise ConfigError(
                f"two inputs would both write {out} (inputs of one file name from different folders): rename one,"
                " or compare them in turn",
                field="inputs",
            )
        seen[resolved] = out


def _one_dataset_and_split(found: dict[Path, tuple[str | None, str | None]]) -> None:
    """Refuse inputs of several datasets or splits: one table compares methods on one split (the scores of
    two splits side by side read as one comparison). Inputs that do not say (a bare scores JSON) fit any."""
    groups: dict[tuple[str, str], list[str]] = {}
    for path, (ds, sp) in found.items():
        if ds is not None or sp is not None:
            groups.setdefault((ds or "?", sp or "?"), []).append(path.name)
    if len(groups) > 1:
        listed = "; ".join(f"{', '.join(names)}: {ds} {sp}" for (ds, sp), names in groups.items())
        raise ConfigError(
            f"a table holds one dataset and split, and the inputs are for {len(groups)}: {listed}"
            " (compare each dataset and split on its own)",
            field="inputs",
        )


def _named_apart(rows: list[MethodRow], paths: list[Path]) -> list[MethodRow]:
    """Rows whose method names are shared (two ``gt`` results, a CSV and its scores JSON) named by their file
    too: ``gt (gt_dimo-real)``; by the path as given where even the file names are the same."""
    counts = Counter(r.method for r in rows)
    named = [
        replace(r, method=f"{r.method} ({p.name.split('.')[0]})") if counts[r.method] > 1 else r
        for r, p in zip(rows, paths, strict=True)
    ]
    counts = Counter(r.method for r in named)
    return [
        replace(n, method=f"{r.method} ({p})") if counts[n.method] > 1 else n
        for r, n, p in zip(rows, named, paths, strict=True)
    ]


def bar_chart(comparison: Comparison, path: Path) -> None:
    """Grouped bars: one group per score, one bar per method (no bar where not available); PNG, written atomically."""
    plt = pyplot()

    rows = comparison.rows
    n = max(1, len(rows))
    width = 0.8 / n
    keys = comparison.keys
    fig, ax = plt.subplots(figsize=(max(7.0, 1.3 * len(keys) + 0.3 * n), 4.2))
    for i, r in enumerate(rows):
        xs = [k + (i - (n - 1) / 2) * width for k, key in enumerate(keys) if r.scores.get(key) is not None]
        ys = [r.scores[key] for key in keys if r.scores.get(key) is not None]
        ax.bar(xs, ys, width=width, label=r.method)
    ax.set_xticks(range(len(keys)), keys, rotation=20, ha="right")
    ax.set_ylim(0, 1)
    ax.set_ylabel("mean average precision" if comparison.protocol == "bop24" else "average recall")
    ax.set_title(comparison.title)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    save_png(fig, path, dpi=120)


def _check_inputs(inputs: list[str | Path]) -> list[Path]:
    """The inputs as paths, each an existing ``.csv`` or ``.json`` file given once."""
    paths = [Path(p) for p in inputs]
    for path in paths:
        if path.suffix not in (".csv", ".json"):
            raise ConfigError(f"expected a results .csv or a scores .json, got {path.name}", field="inputs")
    missing = [str(p) for p in paths if not p.exists()]
    if missing:
        raise ResultsError(f"input file(s) not found: {', '.join(missing)}")
    for path in paths:
        require_file(path, "results .csv or scores .json file", ResultsError)
    seen: dict[Path, Path] = {}
    for path in paths:
        first = seen.setdefault(path.resolve(), path)
        if first is not path:
            raise ConfigError(f"{path} is given twice (as {first}): one row per input", field="inputs")
    return paths
