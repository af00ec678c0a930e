"""The CenDerNet paper's reported numbers as comparison rows: the reference table, read and checked.

``bop_cender/report/paper_tables.csv`` (package data, a copy of ``results/reference/paper_tables.csv`` kept equal
by a test) holds ``dataset,split,method,source,metric,value`` records of BOP'19 scores (the paper reports no
BOP'24 figure); :func:`reference_rows` turns those of one dataset and split into one :class:`MethodRow` per method.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path

from bop_cender.errors import ConfigError
from bop_cender.eval.score_report import SCORE_KEYS, is_recall

#: The paper's reported numbers (dataset, split, method, source, metric, value): package data, so that an
#: installed package finds them (a copy of results/reference/paper_tables.csv, kept equal by a test).
PAPER_TABLES = resources.files("bop_cender.report").joinpath("paper_tables.csv")


@dataclass(frozen=True)
class MethodRow:
    """One row of a comparison: a method's scores (None where not available) and where they come from."""

    method: str
    source: str
    scores: dict[str, float | None]
    dataset: str | None = None
    split: str | None = None


REFERENCE_COLUMNS = ("dataset", "split", "method", "source", "metric", "value")
"""The columns of a reference table (``--reference FILE.csv``), in any order."""


def read_reference_table(path: Path | Traversable) -> list[dict[str, str]]:
    """Every record of a paper-tables CSV (``dataset,split,method,source,metric,value``; ``#`` lines are
    comments), each checked (a number, a known metric), so that a bad table fails before anything is scored.

    Raises:
        ConfigError: the file is missing or malformed.
    """
    if not path.is_file():
        raise ConfigError(
            "reference table not found (expected a CSV such as bop_cender/report/paper_tables.csv)", field=str(path)
        )
    try:
        text = path.read_text(encoding="utf-8-sig")  # a BOM (a spreadsheet's export) is not part of the header
    except UnicodeDecodeError as exc:
        raise ConfigError(f"not UTF-8 text (byte {exc.start}); expected a CSV", field=str(path)) from None
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    header = next(csv.reader(lines[:1]), None)
    if header is None or sorted(h.strip() for h in header) != sorted(REFERENCE_COLUMNS):  # in any order
        found = "no header" if header is None else f"header {','.join(header)}"
        raise ConfigError(f"expected the header {','.join(REFERENCE_COLUMNS)}, found {found}", field=str(path))
    records = []
    first: dict[tuple[str, str, str, str], tuple[str, int]] = {}  # each figure's first value and its row
    for n, rec in enumerate(csv.DictReader(lines, skipinitialspace=True), start=2):  # "a, b" as the header check
        try:
            if not is_recall(float(rec["value"])):
                raise ValueError
            if None in rec or not all(
                isinstance(rec[k], str) for k in ("dataset", "split", "method", "source", "metric")
            ):
                raise TypeError  # a missing column, or more columns than the header (csv keys them None)
        except (KeyError, TypeError, ValueError):
            raise ConfigError(
                f"expected dataset,split,method,source,metric,value (a recall in [0, 1]); bad row {n}", field=str(path)
            ) from None
        if rec["metric"] not in SCORE_KEYS:
            raise ConfigError(
                f"unknown metric {rec['metric']!r} (expected one of {', '.join(SCORE_KEYS)})", field=f"{path}: row {n}"
            )
        value, row = first.setdefault((rec["dataset"], rec["split"], rec["method"], rec["metric"]), (rec["value"], n))
        if float(value) != float(rec["value"]):  # one would be dropped unsaid
            raise ConfigError(
                f"{rec['method']} on {rec['dataset']} {rec['split']} has two values of {rec['metric']}:"
                f" {value} (row {row}) and {rec['value']}",
                field=f"{path}: row {n}",
            )
        records.append(rec)
    return records


def reference_rows(path: Path | Traversable, dataset: str | None, split: str | None) -> list[MethodRow]:
    """Rows of a paper-tables CSV (:func:`read_reference_table`) for ``dataset`` / ``split`` (None: any), one
    per method, its tables merged.

    Raises:
        ConfigError: the file is missing or malformed.
    """
    return reference_rows_of(read_reference_table(path), dataset, split)


def reference_rows_of(records: list[dict[str, str]], dataset: str | None, split: str | None) -> list[MethodRow]:
    """:func:`reference_rows` of records already read."""
    merged: dict[tuple[str, str, str], dict[str, float]] = {}
    sources: dict[tuple[str, str, str], list[str]] = {}
    for rec in records:
        key = (rec["dataset"], rec["split"], rec["method"])
        if (dataset and key[0] != dataset) or (split and key[1] != split):
            continue
        merged.setdefault(key, {})[rec["metric"]] = float(rec["value"])
        if rec["source"] not in sources.setdefault(key, []):
            sources[key].append(rec["source"])
    return [
        MethodRow(f"{key[2]} [reported]", "; ".join(sources[key]), {k: vals.get(k) for k in SCORE_KEYS}, key[0], key[1])
        for key, vals in merged.items()
    ]
