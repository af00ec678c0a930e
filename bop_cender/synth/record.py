"""The record a synthetic dataset keeps at its root: which layout, seed and catalogue made it.

Real DIMO and T-LESS have no such file; ours needs one because a dataset is made by several runs
(``bop-cender synth`` resumes into the same folder) and two of its numbers decide what the folder
means: the catalogue seed (which objects the models folders hold) and the seed (which scenes). A
resumed run with another value would silently mix two datasets (scenes of other objects than the
models, or two seeds' scenes), so :func:`check_or_write_record` refuses it with one error naming the
file and the field. The loaders read only the folders and files of the real layouts, so they never
look at it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from bop_cender.data.bop_io import check_output_dir, save_json
from bop_cender.data.layout import SYNTH_RECORD
from bop_cender.errors import ConfigError, DatasetError

RECORD_FILE = SYNTH_RECORD
#: The synthetic generator's version, in every record (and the demo's cache folder's name,
#: :mod:`bop_cender.synth.demo`): bump it when the generator's output changes, so cached demos are regenerated.
#: v2: the T-LESS layout has one 30-object catalogue (the DIMO demo is byte-identical to v1's, plus the root record
#: bop_cender_synth.json).
GENERATOR_VERSION = "v2"
#: The fields a resumed run must match (the others, the generator version, only inform).
CHECKED_FIELDS = ("layout", "seed", "catalogue_seed")
#: Checked fields a record may lack, with the value their absence means: records written before the field
#: existed, and records of the default appearance (which keep the bytes they always had).
OPTIONAL_FIELDS = {"appearance": "default"}
#: The ``bop-cender synth`` option that sets each checked field.
OPTIONS = {"layout": "--layout", "seed": "--seed", "catalogue_seed": "--catalogue-seed", "appearance": "--appearance"}


def dataset_record(layout: str, spec: Any) -> dict[str, Any]:
    """What the record holds for a generation of ``layout`` with ``spec`` (a DimoSpec or TlessSpec)."""
    record = {
        "generator": "bop-cender synth",
        "generator_version": GENERATOR_VERSION,
        "layout": layout,
        "seed": int(spec.seed),
        "catalogue_seed": int(spec.catalogue_seed),
    }
    for field, default in OPTIONAL_FIELDS.items():
        value = getattr(spec, field, default)
        if value != default:
            record[field] = value
    return record


def check_output_folder(root: str | Path, force: bool = False) -> Path:
    """``root`` if ``bop-cender synth`` may write there: a new or empty folder, or a dataset it made (a record).

    A non-empty folder without a record is someone else's (a real download, a home directory given by
    mistake): the generator would write its models and scenes among what is there, and a later resume
    would take it for a dataset of its own. It is refused unless ``force``.

    Raises:
        ConfigError: ``root`` (or a folder above it) is a file, or a non-empty folder without a record.
    """
    root = check_output_dir(root)
    if force or not root.is_dir() or (root / RECORD_FILE).is_file():
        return root
    found = sorted(p.name for p in root.iterdir())
    if found:
        listed = ", ".join(found[:3]) + (f", ... ({len(found)} in all)" if len(found) > 3 else "")
        raise ConfigError(
            f"not empty ({listed}) and not a dataset bop-cender synth made (no {RECORD_FILE}): give a new or "
            "empty folder, or --force to write into it anyway",
            file=root,
            field="--out",
        )
    return root


def check_or_write_record(root: str | Path, layout: str, spec: Any) -> Path:
    """Write the record into ``root`` if it has none, else check that this run continues the same dataset.

    A folder written before the record existed gets one with this run's values (there is nothing to
    check them against). An existing record's fields are never rewritten here (:func:`mark_complete` sets its
    ``complete`` flag once a run's checks have passed).

    Returns:
        the record's path.

    Raises:
        ConfigError: the record names another layout, seed or catalogue seed (``field``: which).
        DatasetError: the record is not a JSON object with those fields.
    """
    path = Path(root) / RECORD_FILE
    wanted = dataset_record(layout, spec)
    if not path.is_file():
        save_json(path, wanted)
        return path
    try:
        found = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise DatasetError(f"cannot read the dataset record: {e}", file=path) from None
    if not isinstance(found, dict) or any(f not in found for f in CHECKED_FIELDS):
        raise DatasetError(f"expected a JSON object with the fields {', '.join(CHECKED_FIELDS)}", file=path)
    for field in (*CHECKED_FIELDS, *OPTIONAL_FIELDS):
        was, now = (found.get(field, OPTIONAL_FIELDS.get(field)), wanted.get(field, OPTIONAL_FIELDS.get(field)))
        if was != now:
            raise ConfigError(
                f"this dataset was generated with {field} {was!r}, not {now!r}: resuming it "
                f"would mix two datasets (give {OPTIONS[field]} {was}, or another --out)",
                file=path,
                field=field,
            )
    return path


def mark_complete(root: str | Path, complete: bool) -> None:
    """Set the record's ``complete`` field: False when a generation starts, True once its last file is written. A
    generation killed midway left scene folders that the loaders read as the whole dataset; the field lets
    :func:`~bop_cender.data.registry.open_dataset` say so (rerunning the same ``synth`` command completes it). The
    record's other fields are kept as they are."""
    path = Path(root) / RECORD_FILE
    record = json.loads(path.read_text())
    if record.get("complete") is not complete:
        save_json(path, {**record, "complete": complete})
