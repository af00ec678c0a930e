"""Score a results CSV file: find the data it belongs to, score it, write ``scores_<stem>.json`` and ``errors_<stem>.csv``.

Where the data comes from, first found wins for each setting:

1. the options given (``dataset``, ``data_root``, ``split``, ``n_views``, ``seed``);
2. the run sidecar beside the CSV (``<stem>.json``, :func:`bop_cender.results.files.read_run_sidecar`):
   data root, dataset, split, seed and ``n_views`` from its selection;
3. the BOP file name ``{method}_{dataset}-{split}[-{split_type}]...csv``: ``dimo`` and ``tless`` map
   to our loaders, any other name to the generic BOP loader (which then needs a data root);
4. no data root at all for ``dimo`` / ``tless``: what ``open_data`` does with a request without a root
   (the default refuses it; the CLI opens the embedded demo only when asked to, ``--demo``, because a
   results file scored on data it was not made on gives a meaningless 0 rather than an error).

A sidecar that names another dataset than the file name is refused, rows naming scenes, images or
objects that are not in the data are refused by the scorer (each bad line listed), and so is a file
none of whose rows names a target of the data (:func:`check_matching`).
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from bop_cender.data.bop_io import check_output_dir, require_file
from bop_cender.data.registry import DatasetRequest, open_dataset
from bop_cender.data.scene_ids import scene_folder_to_int
from bop_cender.data.types import Dataset
from bop_cender.errors import ConfigError, ResultsError, ResultsWarning
from bop_cender.eval.detection_file import PROTOCOLS, detection_file_outputs, score_detection_rows
from bop_cender.eval.detection_report import DetectionReport, write_detection_files
from bop_cender.eval.render_process import RenderProcess, render_process_useful
from bop_cender.eval.score_report import ScoreReport, write_score_files
from bop_cender.eval.scoring import score_results
from bop_cender.results.bop_csv import check_row_times, read_bop_results
from bop_cender.results.files import (
    ResultName,
    name_contradiction,
    names_split,
    parse_result_filename,
    read_run_sidecar,
    shown_split,
    sidecar_path,
)


@dataclass(frozen=True)
class DataChoice:
    """The dataset a results file is scored on, and where each setting came from.

    Attributes:
        request: what to open (its root None = not given: the caller's ``open_data`` decides, e.g. the demo).
        origin: one line saying where the settings came from.
        scene_keys: the scenes a run covered (its sidecar's ``selection.scene_keys``, written by a run
            with ``--limit-scenes``): only these are scored, so the recall of a partial run is not
            diluted by the targets of scenes it never saw. None: every scene of the split.
        failed_scenes: the scenes the run failed on (its sidecar's ``extra.failed_scenes``): scored as misses,
            and said so.
    """

    request: DatasetRequest
    origin: str
    scene_keys: tuple[str, ...] | None = None
    failed_scenes: tuple[str, ...] = ()
    protocol: str | None = None


@dataclass(frozen=True)
class ScoredFile:
    """A scored results file: the report, the data it was scored on and the files written.

    Attributes:
        report: BOP'19 (:class:`ScoreReport`) or BOP'24 (:class:`~bop_cender.eval.detection_report.DetectionReport`).
        scores_path: its scores JSON. errors_path: its per-estimate CSV (BOP'24: the detections CSV).
        protocol: ``bop19`` or ``bop24``.
    """

    report: ScoreReport | DetectionReport
    choice: DataChoice
    dataset: Dataset
    scores_path: Path
    errors_path: Path
    protocol: str = "bop19"


def choose_data(
    csv_path: str | Path,
    *,
    dataset: str | None = None,
    data_root: str | Path | None = None,
    split: str | None = None,
    n_views: int | None = None,
    seed: int | None = None,
    model_type: str | None = None,
) -> DataChoice:
    """Decide which dataset split ``csv_path`` is scored on (see the module docstring).

    Raises:
        ConfigError: the dataset cannot be told, a sidecar contradicts the file name, or a BOP
            dataset other than dimo/tless has no data root.
        ResultsError: malformed sidecar.
    """
    csv_path = Path(csv_path)
    parsed = _parse_name(csv_path)
    sidecar = read_run_sidecar(csv_path)
    origin = []
    if parsed is not None:  # an option the name (and the sidecar) contradict: a typo would score other data
        said = sidecar or {}
        if (
            dataset is not None
            and dataset != "bop"
            and parsed.dataset != dataset
            and said.get("dataset") in (None, parsed.dataset)
        ):
            _refuse_option("dataset", parsed.dataset, dataset, "dataset" in said)
        if (
            split is not None
            and not names_split(parsed, split)
            and ("split" not in said or names_split(parsed, said["split"]))
        ):
            _refuse_option("split", shown_split(parsed), split, "split" in said)
    if sidecar is not None and parsed is not None and dataset is None and split is None:
        contradiction = name_contradiction(parsed, sidecar["dataset"], sidecar["split"])
        if contradiction is not None:  # renamed after the run: which data the rows belong to is not known
            raise ConfigError(
                f"{contradiction} (its run sidecar {sidecar_path(csv_path).name}); rename the file back, or give"
                " --dataset / --split to choose",
                field="file name",
            )
    name = dataset or (sidecar or {}).get("dataset") or (parsed.dataset if parsed else None)
    if name is None:
        raise ConfigError(
            f"cannot tell the dataset of {csv_path.name}: name it {{method}}_{{dataset}}-{{split}}.csv or give --dataset",
            field="--dataset",
        )
    if name == "bop" and parsed is not None:
        name = parsed.dataset
    if sidecar is not None:
        origin.append(f"run sidecar {csv_path.with_suffix('.json').name}")
    root = data_root if data_root is not None else (sidecar or {}).get("data_root")
    chosen_split = split or (sidecar or {}).get("split") or (parsed.split if parsed else None)
    # the name's split type completes the name's split only (a sidecar's split is already the folder: test_primesense)
    split_type = parsed.split_type if parsed is not None and chosen_split == parsed.split else None
    selection: dict[str, Any] = (sidecar or {}).get("selection", {})
    views = n_views if n_views is not None else selection.get("n_views")
    if n_views is None and views is not None and (isinstance(views, bool) or not isinstance(views, int) or views < 1):
        raise ResultsError(f"selection.n_views: expected a positive integer or null, got {views!r}",
                           file=sidecar_path(csv_path))  # fmt: skip
    seed_value = seed if seed is not None else int((sidecar or {}).get("seed", 0))
    if model_type is None:  # the models folder the run read (BOP: --model-type cad), unless given now
        model_type = ((sidecar or {}).get("extra") or {}).get("model_type")
        if model_type is not None and not (isinstance(model_type, str) and model_type):
            raise ResultsError(f"extra.model_type: expected a models folder type or null, got {model_type!r}",
                               file=sidecar_path(csv_path))  # fmt: skip
    request = DatasetRequest(
        dataset=name, root=None if root is None else Path(root), split=chosen_split or None,
        n_views=None if views is None else int(views), seed=seed_value, model_type=model_type, split_type=split_type,
    )  # fmt: skip
    if root is None and request.loader == "bop":
        raise ConfigError(f"dataset {name!r} needs --data-root DIR (a folder in the BOP layout)", field="--data-root")
    if parsed is not None:
        origin.append(f"file name ({parsed.dataset}-{parsed.split}{'-' + split_type if split_type else ''})")
    if dataset or data_root or split:
        origin.insert(0, "options")
    keys = selection.get("scene_keys")
    if keys is not None and not (isinstance(keys, list) and all(isinstance(k, str) for k in keys) and keys):
        raise ResultsError("selection.scene_keys: expected a non-empty list of scene keys", file=sidecar_path(csv_path))
    failed = (sidecar or {}).get("extra", {}).get("failed_scenes") or {}
    if not (isinstance(failed, dict) and all(isinstance(k, str) for k in failed)):
        raise ResultsError("extra.failed_scenes: expected an object of scene keys", file=sidecar_path(csv_path))
    protocol = (sidecar or {}).get("extra", {}).get("protocol")
    if protocol is not None and protocol not in PROTOCOLS:
        raise ResultsError(f"extra.protocol: expected one of {', '.join(PROTOCOLS)}, got {protocol!r}",
                           file=sidecar_path(csv_path))  # fmt: skip
    return DataChoice(
        request, ", ".join(origin) or "defaults", None if keys is None else tuple(keys), tuple(failed), protocol
    )


def _refuse_option(what: str, named: str, given: str, sidecar_too: bool) -> None:
    """The error for ``--dataset`` / ``--split`` giving ``given`` where the file name (and its sidecar) say ``named``.

    Raises:
        ConfigError: always, naming the option.
    """
    raise ConfigError(
        f"the file name{' and its run sidecar say' if sidecar_too else ' says'} {what} {named!r}, not {given!r}:"
        f" results of one {what} are not scored on another (rename the file if its results are of {given!r})",
        field=f"--{what}",
    )


def score_file_outputs(csv_path: str | Path, out_dir: str | Path | None = None) -> tuple[Path, Path]:
    """``(scores_<stem>.json, errors_<stem>.csv)`` that :func:`score_file` writes for ``csv_path`` into ``out_dir``
    (default: beside the CSV)."""
    csv_path = Path(csv_path)
    out = Path(out_dir) if out_dir is not None else csv_path.parent
    stem = csv_path.name.split(".")[0]
    return out / f"scores_{stem}.json", out / f"errors_{stem}.csv"


def score_file(
    csv_path: str | Path,
    *,
    dataset: str | None = None,
    data_root: str | Path | None = None,
    split: str | None = None,
    n_views: int | None = None,
    seed: int | None = None,
    model_type: str | None = None,
    vsd_delta: float | None = None,
    out_dir: str | Path | None = None,
    progress: bool = True,
    render_process: RenderProcess | bool | None = None,
    open_data: Callable[[DatasetRequest], Dataset] = open_dataset,
    write: bool = True,
    protocol: str | None = None,
) -> ScoredFile:
    """Score one BOP results CSV and write ``scores_<stem>.json`` and ``errors_<stem>.csv`` into ``out_dir``.

    A file that cannot be a meaningful score is refused rather than scored 0: one with no estimate
    (empty, blank, header only), and one none of whose rows names a target of the data (results of
    other data, or the wrong data root). When fewer than :data:`MIN_MATCHING_FRACTION` of the rows
    match a target, a :class:`~bop_cender.errors.ResultsWarning` says so (the score stands: the rest
    are ignored, as the toolkit ignores them).

    Args:
        csv_path: the results file.
        dataset, data_root, split, n_views, seed, model_type: override what the sidecar / file name say.
        vsd_delta: VSD delta (mm); default the toolkit's.
        out_dir: where to write (default: beside the CSV).
        render_process: render VSD depth in a forked process (:mod:`bop_cender.eval.render_process`):
            one already started (left open), True to start one, False for threads of this process;
            None = start one where it helps: ``fork`` exists and torch is not imported yet (a cold start).
        open_data: opens the chosen request (default :func:`~bop_cender.data.registry.open_dataset`, which
            needs a data root; the CLI passes :func:`bop_cender.datasets.open_with_demo` for ``--demo``).
        write: write the two files (both or neither, :func:`write_score_files`); False = only score
            (``compare`` writes once every input has been scored).
        protocol: ``bop19`` (BOP'19 localisation: AR) or ``bop24`` (BOP'24/'25 detection: mAP,
            :mod:`bop_cender.eval.detection_file`); None: the run sidecar's ``extra.protocol``, else ``bop19``.

    Raises:
        ResultsError: the file is missing, a directory, malformed, holds no estimate, or matches no target.
    """
    csv_path = require_file(csv_path, "results file", ResultsError)  # before the data is opened
    if protocol is not None and protocol not in PROTOCOLS:
        raise ConfigError(f"expected one of {', '.join(PROTOCOLS)}, got {protocol!r}", field="--protocol")
    if out_dir is not None:
        check_output_dir(out_dir)
    clock = time.perf_counter()
    # every line checked before the data is opened (or the demo generated); the times below, once the protocol is known
    rows = read_bop_results(csv_path, check_times=False)
    if not rows:
        raise ResultsError("no estimates (the file is empty or holds only the header): nothing to score", file=csv_path)
    read = time.perf_counter()
    choice = choose_data(
        csv_path, dataset=dataset, data_root=data_root, split=split, n_views=n_views, seed=seed, model_type=model_type
    )
    protocol = protocol or choice.protocol or PROTOCOLS[0]
    if protocol == "bop19":
        check_row_times(rows, csv_path)  # every row; BOP'24 checks the rows its cap keeps
    else:  # the one place the protocol is chosen
        ds = restrict_scenes(open_data(choice.request), choice.scene_keys, csv_path)
        check_millimetres(rows, ds, csv_path)
        report = score_detection_rows(
            rows, ds, csv_path, progress=progress, method=method_name(csv_path), origin=choice.origin
        )
        report.timings.update(read_results=read - clock, total=time.perf_counter() - clock)
        scored = ScoredFile(report, choice, ds, *detection_file_outputs(csv_path, out_dir), protocol="bop24")
        if write:
            write_scored(scored)
        return scored
    if isinstance(render_process, RenderProcess):
        process = nullcontext(render_process)
    elif render_process or (render_process is None and render_process_useful()):
        # Started first, so that the child's torch import runs while this process reads the data.
        process = RenderProcess.start()
    else:
        process = nullcontext()
    with process as renderer:
        ds = restrict_scenes(open_data(choice.request), choice.scene_keys, csv_path)
        check_millimetres(rows, ds, csv_path)
        opened = time.perf_counter()
        report = score_results(rows, ds, vsd_delta=vsd_delta, progress=progress, source=csv_path, renderer=renderer)
    report.timings.update(read_results=read - clock, open_dataset=opened - read)
    report = replace(report, metadata=replace(report.metadata, data_origin=choice.origin, method=method_name(csv_path)))
    check_matching(report, csv_path, choice)
    check_failed_scenes(choice.failed_scenes, ds, rows, csv_path)
    if choice.failed_scenes:
        shown = ", ".join(choice.failed_scenes[:5]) + (" ..." if len(choice.failed_scenes) > 5 else "")
        message = (
            f"the run failed on {len(choice.failed_scenes)} scene(s) ({shown}; see its sidecar): their targets count"
            " as misses"
        )
        report.notes.append(message)
        warnings.warn(f"{csv_path}: {message}", ResultsWarning, stacklevel=2)
    scored = ScoredFile(report, choice, ds, *score_file_outputs(csv_path, out_dir))
    report.timings["total"] = time.perf_counter() - clock
    if write:
        write_scored(scored)
    return scored


def write_scored(scored: ScoredFile) -> None:
    """Write a scored file's scores JSON and errors (BOP'24: detections) CSV, both or neither."""
    if isinstance(scored.report, DetectionReport):
        write_detection_files(scored.scores_path, scored.errors_path, scored.report)
    else:
        write_score_files(scored.scores_path, scored.errors_path, scored.report)


#: Below this fraction of rows naming a target, scoring warns (the rest are ignored): a file made on other
#: data, or scored on the wrong split, would otherwise give a low score without a word.
MIN_MATCHING_FRACTION = 0.5


#: Below this median distance from the camera, in model diameters, the objects would be inside the camera: t in
#: metres (a part 700 mm away written as 0.7 is 0.005 diameters of a 140 mm part).
MIN_DISTANCE_IN_DIAMETERS = 0.5
#: ... and the median distance under this many millimetres (a figure that reads as metres: 0.5-2 for a bin camera).
MAX_METRES_LIKE_MM = 10.0


def check_millimetres(rows: list, ds: Dataset, csv_path: Path) -> None:
    """Refuse translations that cannot be in millimetres (BOP's unit): written in metres, every estimate is
    "farther than the loosest threshold" and the file scores 0 with no other sign. The median over the rows of
    known objects is judged (rows with t = 0, a method's placeholder, left out), so that a few wild estimates do
    not refuse a file; it must be under half a diameter and under :data:`MAX_METRES_LIKE_MM`.

    Raises:
        ResultsError: the objects would lie a median of under :data:`MIN_DISTANCE_IN_DIAMETERS` diameters from
            the camera.
    """
    known = [r for r in rows if r.obj_id in ds.models]
    if not known:
        return
    with np.errstate(over="ignore"):  # a row's t of 1e300 mm is a miss (inf), as scored; not a warning here
        distances = np.linalg.norm(np.stack([r.t for r in known]), axis=1)
    placed = distances > 0  # t = 0: a method's placeholder for "not found"
    if not placed.any():
        raise ResultsError(
            f"every estimate ({len(known)}) has t = 0: placeholders, no pose to score", file=csv_path, field="t"
        )
    diameters = np.array([ds.models[r.obj_id].diameter for r in known])
    median = float(np.median(distances[placed] / diameters[placed]))
    distance = float(np.median(distances[placed]))
    if median < MIN_DISTANCE_IN_DIAMETERS and distance < MAX_METRES_LIKE_MM:
        raise ResultsError(
            f"implausible translations: the objects would lie a median {median:.3g} model diameters ({distance:.3g}"
            " mm) from the camera, inside it; BOP results give t in millimetres: were they in metres? multiply them"
            " by 1000",
            file=csv_path,
            field="t",
        )


def check_matching(report: ScoreReport, csv_path: Path, choice: DataChoice) -> None:
    """Refuse a file none of whose rows names a target of the data; warn when only a fraction does.

    Rows that name no target (images the split does not select, objects that are not targets of their
    image) are ignored, as the toolkit ignores them; when that is every row the score is 0 whatever the
    poses, which only says that the file and the data do not belong together.

    Raises:
        ResultsError: no row names a target.
    """
    meta, counts = report.metadata, report.metadata.counts
    matching = counts.rows - counts.not_target
    if counts.rows == 0 or matching / counts.rows >= MIN_MATCHING_FRACTION:
        return
    where = f"dataset {meta.dataset} {meta.split} at {meta.root}"
    ignored = f"{counts.unselected_images} for images the split does not select" if counts.unselected_images else ""
    other = counts.not_target - counts.unselected_images
    ignored = "; ".join(
        p for p in (ignored, f"{other} for images or objects that are not targets" if other else "") if p
    )
    hint = f"the data came from {choice.origin}: wrong --data-root or --split?"
    if matching == 0:
        raise ResultsError(f"0 of {counts.rows} rows match a target of {where} ({ignored}); {hint}", file=csv_path)
    message = (
        f"only {matching} of {counts.rows} rows ({100 * matching / counts.rows:.0f} %) match a target of {where}; "
        f"the other {counts.not_target} are ignored ({ignored}); {hint}"
    )
    report.notes.append(message)
    warnings.warn(f"{csv_path}: {message}", ResultsWarning, stacklevel=3)


def check_failed_scenes(failed: tuple[str, ...], ds: Dataset, rows: list, csv_path: Path) -> None:
    """Refuse a sidecar whose failed scenes do not belong to the file: scenes outside the scored split, or
    scenes the CSV has rows for (a run writes none for a scene it failed on; the note that their targets
    count as misses would then be false).

    Raises:
        ResultsError: naming the sidecar and ``extra.failed_scenes``.
    """
    if not failed:
        return
    where = {"file": sidecar_path(csv_path), "field": "extra.failed_scenes"}
    scored = set(ds.scene_keys)
    unknown = [k for k in failed if k not in scored]
    if unknown:
        raise ResultsError(
            f"names {len(unknown)} scene(s) that are not among the {len(ds.scene_keys)} scored: "
            f"{', '.join(unknown[:5])}",
            **where,
        )
    images = {(r.scene_id, r.im_id) for r in rows}
    for key in failed:
        scene = ds.scene(key)
        scene_int = scene_folder_to_int(scene.scene_id)
        n = sum((scene_int, im) in images for im in scene.im_ids)
        if n:
            raise ResultsError(
                f"says the run failed on scene {key}, but {csv_path.name} has rows for {n} of its images: "
                "the sidecar is not this file's",
                **where,
            )


def restrict_scenes(ds: Dataset, keys: tuple[str, ...] | None, csv_path: Path) -> Dataset:
    """``ds`` with only the scenes ``keys`` (in the split's order); every key must be in the split."""
    if keys is None:
        return ds
    missing = sorted(set(keys) - set(ds.scene_keys))
    if missing:
        raise ResultsError(
            f"the run sidecar names {len(missing)} scene(s) the split does not have: {', '.join(missing[:5])}",
            file=sidecar_path(csv_path),
            field="selection.scene_keys",
        )
    wanted = set(keys)
    selection = [*ds.selection, f"scenes: the {len(wanted)} of {len(ds.scene_keys)} that the run covered (its sidecar)"]
    return replace(ds, scene_keys=[k for k in ds.scene_keys if k in wanted], selection=selection, _cache={})


def method_name(path: str | Path) -> str:
    """The method a results or scores file is for: the BOP name's method part, else the file stem."""
    name = Path(path).name
    if name.startswith("scores_"):
        name = name[len("scores_") :]
    parsed = _parse_name(Path(name))
    return parsed.method if parsed is not None else name.split(".")[0]


def _parse_name(path: Path) -> ResultName | None:
    try:
        return parse_result_filename(path.name)
    except ResultsError:
        return None
