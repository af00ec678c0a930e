"""BOP result file names and the run sidecar JSON written beside a results CSV.

The official toolkit parses ``{method}_{dataset}-{split}[-{split_type}][_{optional_id}].csv`` by
splitting on ``_`` then ``-``; these helpers build and parse names the same way and refuse names it
would misread. The sidecar records where a run's data came from so ``bop-cender score`` can find it.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bop_cender.data.bop_io import load_json, save_json
from bop_cender.errors import ConfigError, ResultsError, ResultsWarning

SIDECAR_FORMAT = "bop-cender-run"
SIDECAR_VERSION = 1


@dataclass(frozen=True)
class ResultName:
    """The parts of a BOP result file name ``{method}_{dataset}-{split}[-{split_type}][_{optional_id}].csv``."""

    method: str
    dataset: str
    split: str
    split_type: str | None = None
    optional_id: str | None = None

    def filename(self, ext: str = "csv") -> str:
        """The file name these parts make (inverse of :func:`parse_result_filename`)."""
        parts = "-".join(p for p in (self.dataset, self.split, self.split_type) if p)
        tail = f"_{self.optional_id}" if self.optional_id else ""
        return f"{self.method}_{parts}{tail}.{ext}"


def parse_result_filename(name: str | Path) -> ResultName:
    """Parse ``{method}_{dataset}-{split}[-{split_type}][_{optional_id}].{ext}`` as the toolkit does.

    Like ``inout.parse_result_filename``: the extension is everything after the first ``.``, the
    rest is split on ``_`` (method, dataset-split, optional id) and the second part on ``-``. Names
    the toolkit would read differently from what they say are refused: no ``_`` or no ``-``, an
    empty part, or a fourth ``-`` part (the toolkit would silently drop it).

    Raises:
        ResultsError: the name does not follow the pattern.
    """
    base = Path(name).name
    stem = base.split(".")[0]
    parts = stem.split("_")
    expected = "expected {method}_{dataset}-{split}[-{split_type}][_{optional_id}].csv (no '_' in the method)"
    if len(parts) < 2:
        raise ResultsError(f"no '_' after the method name; {expected}", file=base, field="file name")
    ds = parts[1].split("-")
    optional_id = "_".join(parts[2:]) or None
    if len(ds) not in (2, 3) or not all(ds) or not all(parts):
        raise ResultsError(f"cannot read method/dataset/split from {stem!r}; {expected}", file=base, field="file name")
    return ResultName(parts[0], ds[0], ds[1], ds[2] if len(ds) == 3 else None, optional_id)


def result_filename(
    method: str, dataset: str, split: str, split_type: str | None = None, optional_id: str | None = None
) -> str:
    """``{method}_{dataset}-{split}[-{split_type}][_{optional_id}].csv``, checked to parse back the same.

    BOP names a ``train_pbr`` folder as split ``train``, split type ``pbr``.

    Raises:
        ConfigError: a part is empty or contains a character the toolkit splits on (``_`` in the
            method; ``_``, ``-`` in dataset/split/split type; ``.`` anywhere).
    """
    checks = [("method", method, "_."), ("dataset", dataset, "_-."), ("split", split, "_-.")]
    if split_type is not None:
        checks.append(("split_type", split_type, "_-."))
    if optional_id is not None:
        checks.append(("optional_id", optional_id, "."))
    for what, value, bad in checks:
        if not value or any(c in value for c in bad) or "/" in value:
            raise ConfigError(
                f"{value!r} cannot be a BOP result-name part: must be non-empty without {' '.join(bad)} or /",
                field=what,
            )
    return ResultName(method, dataset, split, split_type, optional_id).filename()


def name_contradiction(name: ResultName, dataset: str, split: str) -> str | None:
    """How a result file name contradicts the dataset and split of the results it holds; None where it does not.

    The toolkit and ``score`` read the data from the name: a file named for another split would be scored on it.
    A run on ``--dataset bop`` (any BOP dataset, by its folder) agrees with every dataset part; a split folder
    ``train_pbr`` agrees with the name's split ``train`` and split type ``pbr`` (BOP's naming).
    """
    if dataset != "bop" and name.dataset != dataset:
        return f"the file name says dataset {name.dataset!r}, the results are of {dataset!r}"
    if not names_split(name, split):
        return f"the file name says split {shown_split(name)!r}, the results are of {split!r}"
    return None


def names_split(name: ResultName, split: str) -> bool:
    """Whether result file name ``name`` names split folder ``split``: a split type names the folder
    ``{split}_{type}``; an optional id after a split may be the rest of an underscore split (the default names
    before BOP's naming: cendernet-net_tless-train_pbr.csv)."""
    named = {f"{name.split}_{name.split_type}"} if name.split_type else {name.split}
    if name.split_type is None and name.optional_id:
        named.add(f"{name.split}_{name.optional_id}")
    return split in named


def shown_split(name: ResultName) -> str:
    """The split of result file name ``name`` as it reads in the name (``train-pbr``)."""
    return name.split + (f"-{name.split_type}" if name.split_type else "")


def default_result_filename(method: str, dataset: str, split: str) -> str:
    """The result file name of ``method`` on a split folder (``train_pbr`` named split ``train``, type ``pbr``)."""
    main, _, split_type = split.partition("_")
    return result_filename(method, dataset, main, split_type or None)


def sidecar_path(csv_path: str | Path) -> Path:
    """The run sidecar beside a results CSV: ``<csv stem>.json``."""
    csv_path = Path(csv_path)
    return csv_path.with_name(csv_path.name.split(".")[0] + ".json")


def write_run_sidecar(
    csv_path: str | Path,
    data_root: str | Path,
    dataset: str,
    split: str,
    selection: Mapping[str, Any],
    seed: int,
    extra: Mapping[str, Any] | None = None,
) -> Path:
    """Record how a results CSV was made (data root, dataset, split, selection, seed) in ``<stem>.json``.

    ``bop-cender score`` reads it to find the data the results belong to. No time stamp is written,
    so the same run writes the same bytes. Returns the sidecar path.
    """
    if not isinstance(seed, int) or isinstance(seed, bool):
        raise ConfigError(f"seed must be an int, got {seed!r}", field="seed")
    content = {
        "format": SIDECAR_FORMAT,
        "version": SIDECAR_VERSION,
        "results": Path(csv_path).name,
        "data_root": str(Path(data_root).resolve()),
        "dataset": dataset,
        "split": split,
        "selection": dict(selection),
        "seed": seed,
        "extra": dict(extra or {}),
    }
    path = sidecar_path(csv_path)
    save_json(path, content)
    return path


_SIDECAR_TYPES = {"format": str, "version": int, "data_root": str, "dataset": str, "split": str,
                  "selection": dict, "seed": int, "extra": dict}  # fmt: skip


def read_run_sidecar(csv_path: str | Path) -> dict[str, Any] | None:
    """The sidecar of a results CSV as a dict, or None when there is none.

    Raises:
        ResultsError: the sidecar is not JSON, not ours, or a key is missing, of the wrong type or of a value no
            run writes (an empty data root, a negative seed).

    A relative ``data_root`` (a hand-written sidecar) is taken from the sidecar's folder, as paths in a
    configuration file are, and returned absolute; a ``results`` name other than the CSV's is a
    :class:`~bop_cender.errors.ResultsWarning` (a renamed pair is scored, and says so).
    """
    path = sidecar_path(csv_path)
    if not path.exists():
        return None
    data = load_json(path, error=ResultsError)
    if not isinstance(data, dict) or data.get("format") != SIDECAR_FORMAT:
        raise ResultsError(f"not a run sidecar (expected an object with format {SIDECAR_FORMAT!r})", file=path)
    problems = [
        f"{key}: expected {kind.__name__}, got {type(data.get(key)).__name__}"
        for key, kind in _SIDECAR_TYPES.items()
        if not isinstance(data.get(key), kind) or (kind is int and isinstance(data.get(key), bool))
    ]
    if not problems:
        problems = _sidecar_value_problems(data)
    if problems:
        raise ResultsError("malformed run sidecar", file=path, problems=problems)
    if data["version"] > SIDECAR_VERSION:
        raise ResultsError(
            f"sidecar version {data['version']} is newer than this bop-cender's {SIDECAR_VERSION}", file=path
        )
    csv_name = Path(csv_path).name
    if data.get("results") not in (None, csv_name):  # a renamed pair (or another file's sidecar): said, then used
        warnings.warn(
            f"{path}: results: the sidecar was written for {data['results']}, not {csv_name}; using it for {csv_name}",
            ResultsWarning,
            stacklevel=2,
        )
    root = Path(data["data_root"]).expanduser()
    data["data_root"] = str(root if root.is_absolute() else (path.parent / root).resolve())
    return data


def _sidecar_value_problems(data: Mapping[str, Any]) -> list[str]:
    """``field: problem`` for each value of a well-typed sidecar that no run writes (a hand edit, or damage)."""
    problems = []
    if data["version"] < 1:
        problems.append(f"version: expected 1 to {SIDECAR_VERSION}, got {data['version']}")
    if data["seed"] < 0:
        problems.append(f"seed: expected a non-negative integer, got {data['seed']}")
    for key in ("data_root", "dataset", "split"):
        if not data[key].strip():
            problems.append(f"{key}: expected a non-empty string, got {data[key]!r}")
    if "results" in data and not (isinstance(data["results"], str) and data["results"].strip()):
        problems.append(f"results: expected the results file's name, got {data['results']!r}")
    return problems
