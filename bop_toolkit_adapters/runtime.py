"""Run the official BOP toolkit's evaluation scripts in this process, on an export, with datasets registered at run time.

Nothing of the toolkit is edited or copied. For the duration of :func:`registered`,
``bop_toolkit_lib.dataset_params.get_split_params`` and ``get_model_params`` are wrapped so that
the exported dataset resolves to the export's folders: a dataset the toolkit knows (T-LESS) keeps
its own parameters with only the object and scene ids narrowed to what was exported (the toolkit
would otherwise load all 30 T-LESS models); an unknown name (DIMO, custom) gets classic-BOP
parameters built from the export. The VSD delta of an unknown dataset is passed to
``eval_calc_errors.py`` the way ``eval_bop19_pose.py`` passes its table: ``--vsd_deltas=name:delta``.

:func:`evaluate` then does what ``scripts/eval_bop19_pose.py`` does, without its 120 Python
processes: ``eval_calc_errors.py`` once per error type and ``eval_calc_scores.py`` once per
(error folder, threshold), each run with ``runpy`` and its own ``sys.argv``, and the average recalls
computed from the ``scores_*.json`` files the scripts wrote, as eval_bop19_pose.py computes them.
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import runpy
import sys
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
from tqdm import tqdm

from bop_cender.errors import BopCenderError
from bop_toolkit_adapters.export import ToolkitExport

#: The BOP'19 settings of eval_bop19_pose.py (thresholds with np.arange's float noise).
VSD_TAUS = list(np.arange(0.05, 0.51, 0.05))
CORRECT_TH = {"vsd": list(np.arange(0.05, 0.51, 0.05)), "mssd": list(np.arange(0.05, 0.51, 0.05)),
              "mspd": list(np.arange(5, 51, 5))}  # fmt: skip


class ToolkitUnavailable(RuntimeError):
    """The toolkit (or, for VSD, its renderer) cannot be imported; the message says why."""


class ToolkitRunError(BopCenderError):
    """One of the toolkit's scripts failed on the exported input (the message has the end of its output)."""


@dataclass
class ToolkitScores:
    """What the toolkit computed.

    Attributes:
        recalls: per error type, the recall per threshold (VSD: tau-major, 10 x 10 flattened).
        average_recalls: per error type, the mean of its recalls; ``bop19`` = mean of the three.
        errors: per error type, ``(scene_id, im_id, obj_id, est_id, gt_id) -> raw errors`` (VSD: per tau).
        skipped: error types not computed, with the reason.
    """

    recalls: dict[str, list[float]] = field(default_factory=dict)
    average_recalls: dict[str, float] = field(default_factory=dict)
    errors: dict[str, dict[tuple[int, int, int, int, int], list[float]]] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)


def import_toolkit(toolkit_dir: str | Path | None) -> tuple[ModuleType, Path]:
    """Import ``bop_toolkit_lib`` (from ``toolkit_dir`` first, else the environment); return it and its scripts folder.

    Raises:
        ToolkitUnavailable: not importable (the import error is in the message), or no ``scripts/``.
    """
    if toolkit_dir is not None:
        if not (Path(toolkit_dir) / "bop_toolkit_lib").is_dir():  # else an import made earlier would pass for it
            raise ToolkitUnavailable(
                f"the BOP toolkit (bop_toolkit_lib) is not importable from {toolkit_dir}: no bop_toolkit_lib folder there"
            )
        path = str(Path(toolkit_dir).resolve())
        if path not in sys.path:
            sys.path.insert(0, path)
    try:
        import bop_toolkit_lib
        from bop_toolkit_lib import dataset_params, inout, misc  # noqa: F401  (their imports must work)
    except ImportError as e:
        where = f" from {toolkit_dir}" if toolkit_dir is not None else ""
        raise ToolkitUnavailable(f"the BOP toolkit (bop_toolkit_lib) is not importable{where}: {e}") from None
    root = Path(bop_toolkit_lib.__file__).resolve().parents[1]
    scripts = root / "scripts"
    if not (scripts / "eval_calc_errors.py").is_file():
        raise ToolkitUnavailable(
            f"bop_toolkit_lib found at {root}, but not its scripts/ folder (a full checkout is needed)"
        )
    return bop_toolkit_lib, scripts


def vsd_renderer_available() -> str | None:
    """None if the toolkit's vispy renderer can be created headless (EGL), else why not."""
    os.environ.setdefault("EGL_PLATFORM", "surfaceless")  # Mesa EGL without a display
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            from bop_toolkit_lib.rendering import renderer

            renderer.create_renderer(64, 48, "vispy", mode="depth")
    except Exception as e:  # noqa: BLE001  (any failure means: no VSD through the toolkit)
        return f"{type(e).__name__}: {e}".splitlines()[0]
    return None


@contextlib.contextmanager
def registered(export: ToolkitExport, phase: str) -> Iterator[None]:
    """Make ``dataset_params`` resolve ``export.dataset`` to the export, for ``phase`` ``errors`` or ``scores``.

    The image size is the images' own for ``errors`` (VSD renders at it) and, for ``scores``, has the
    width MSPD is normalised with (the toolkit's constant for a dataset it knows).
    """
    from bop_toolkit_lib import dataset_params as dp

    original_split, original_model = dp.get_split_params, dp.get_model_params
    width = export.im_size[0] if phase == "errors" else export.mspd_width
    im_size = (width, export.im_size[1])

    def get_split_params(datasets_path: str, dataset_name: str, split: str, split_type: str | None = None) -> dict:
        if dataset_name != export.dataset:
            return original_split(datasets_path, dataset_name, split, split_type)
        if export.known_to_toolkit:
            p = original_split(datasets_path, dataset_name, split, split_type)
        else:
            p = _classic_split_params(datasets_path, export, split, split_type)
        p["scene_ids"] = list(export.scene_ids)
        p["im_size"] = im_size
        return p

    def get_model_params(datasets_path: str, dataset_name: str, model_type: str | None = None) -> dict:
        if dataset_name != export.dataset:
            return original_model(datasets_path, dataset_name, model_type)
        models = os.path.join(datasets_path, dataset_name, "models_eval")
        return {
            "obj_ids": list(export.obj_ids),
            "symmetric_obj_ids": [],
            "model_tpath": os.path.join(models, "obj_{obj_id:06d}.ply"),
            "models_info_path": os.path.join(models, "models_info.json"),
        }

    dp.get_split_params, dp.get_model_params = get_split_params, get_model_params
    try:
        yield
    finally:
        dp.get_split_params, dp.get_model_params = original_split, original_model


def evaluate(
    export: ToolkitExport, scripts: Path, with_vsd: bool, quiet: bool = True, progress: bool = True
) -> ToolkitScores:
    """The BOP'19 evaluation of the exported results by the toolkit's own scripts (see the module docstring).

    Raises:
        ToolkitRunError: a script exits non-zero or raises.
    """
    out = ToolkitScores()
    error_types = ["vsd", "mssd", "mspd"] if with_vsd and export.vsd_delta is not None else ["mssd", "mspd"]
    runs = sum(1 + len(_error_signs(err, export)) * len(CORRECT_TH[err]) for err in error_types)
    bar = tqdm(total=runs, desc="BOP toolkit", unit="script", disable=not progress)
    if "vsd" not in error_types:
        out.skipped["vsd"] = "no test depth" if export.vsd_delta is None else "the toolkit's renderer is not available"
    common = [f"--datasets_path={export.datasets_path}", f"--eval_path={export.eval_path}",
              "--targets_filename=test_targets_bop19.json"]  # fmt: skip
    for err in error_types:
        args = [f"--error_type={err}", "--n_top=-1", f"--result_filenames={export.result_filename}",
                f"--results_path={export.results_path}", "--renderer_type=vispy", "--num_workers=1",
                "--skip_missing=1", *common]  # fmt: skip
        if err == "vsd":
            args += [f"--vsd_deltas={export.dataset}:{export.vsd_delta}", f"--vsd_taus={','.join(map(str, VSD_TAUS))}",
                     "--vsd_normalized_by_diameter=True"]  # fmt: skip
        with registered(export, "errors"):
            _run(scripts / "eval_calc_errors.py", args, quiet)
        bar.update()
        signs = _error_signs(err, export)
        out.errors[err] = _read_errors(export, signs)
        recalls = []
        with registered(export, "scores"):
            for sign in signs:
                for th in CORRECT_TH[err]:
                    _run(scripts / "eval_calc_scores.py",
                         [f"--error_dir_paths={os.path.join(export.result_name, sign)}", "--visib_gt_min=-1",
                          f"--correct_th_{err}={th}", *common], quiet)  # fmt: skip
                    recalls.append(_read_recall(export, sign, th))
                    bar.update()
        out.recalls[err] = recalls
        out.average_recalls[err] = float(np.mean(recalls))
    bar.close()
    if len(out.average_recalls) == 3:
        out.average_recalls["bop19"] = float(np.mean([out.average_recalls[k] for k in ("vsd", "mssd", "mspd")]))
    return out


def _classic_split_params(datasets_path: str, export: ToolkitExport, split: str, split_type: str | None) -> dict:
    """dataset_params.get_split_params's classic-BOP dict for a dataset it does not know."""
    base = os.path.join(datasets_path, export.dataset)
    split_path = os.path.join(base, split + (f"_{split_type}" if split_type else ""))
    scene = os.path.join(split_path, "{scene_id:06d}")
    return {
        "name": export.dataset, "split": split, "split_type": split_type, "base_path": base,
        "depth_range": None, "azimuth_range": None, "elev_range": None,
        "im_modalities": ["rgb", "depth"], "eval_sensor": None, "eval_modality": None,
        "supported_error_types": ["ad", "add", "adi", "vsd", "mssd", "mspd", "cus", "proj"],
        "split_path": split_path,
        "rgb_tpath": os.path.join(scene, "rgb", "{im_id:06d}.png"),
        "gray_tpath": os.path.join(scene, "gray", "{im_id:06d}.png"),
        "depth_tpath": os.path.join(scene, "depth", "{im_id:06d}.png"),
        "scene_camera_tpath": os.path.join(scene, "scene_camera.json"),
        "scene_gt_tpath": os.path.join(scene, "scene_gt.json"),
        "scene_gt_info_tpath": os.path.join(scene, "scene_gt_info.json"),
        "scene_gt_coco_tpath": os.path.join(scene, "scene_gt_coco.json"),
        "mask_tpath": os.path.join(scene, "mask", "{im_id:06d}_{gt_id:06d}.png"),
        "mask_visib_tpath": os.path.join(scene, "mask_visib", "{im_id:06d}_{gt_id:06d}.png"),
    }  # fmt: skip


def _run(script: Path, args: list[str], quiet: bool) -> None:
    """Run a toolkit script in this process, as ``python script args``; raise if it exits non-zero.

    ``quiet`` silences its prints, its log up to warnings (e.g. the HOT3D dependency notice) and its
    Python warnings; errors still show.
    """
    argv = sys.argv
    sys.argv = [str(script), *args]
    sink = io.StringIO()
    if quiet:
        logging.disable(logging.WARNING)
    try:
        with contextlib.redirect_stdout(sink) if quiet else contextlib.nullcontext(), warnings.catch_warnings():
            if quiet:
                warnings.simplefilter("ignore")
            runpy.run_path(str(script), run_name="__main__")
    except SystemExit as e:
        if e.code not in (0, None):
            raise ToolkitRunError(f"exited with {e.code}: {sink.getvalue()[-2000:]}", file=script) from None
    except Exception as e:  # noqa: BLE001 - the toolkit's own failure, reported as one error naming its script
        raise ToolkitRunError(f"failed: {type(e).__name__}: {e}", file=script) from e
    finally:
        sys.argv = argv
        if quiet:
            logging.disable(logging.NOTSET)


def _error_signs(err: str, export: ToolkitExport) -> list[str]:
    from bop_toolkit_lib import misc

    if err == "vsd":
        return [misc.get_error_signature("vsd", -1, vsd_delta=export.vsd_delta, vsd_tau=t) for t in VSD_TAUS]
    return [misc.get_error_signature(err, -1)]


def _read_recall(export: ToolkitExport, sign: str, th: float) -> float:
    from bop_toolkit_lib import inout, misc

    path = export.eval_path / export.result_name / sign / f"scores_{misc.get_score_signature([th], -1)}.json"
    recall = inout.load_json(str(path))["recall"]
    if isinstance(recall, bool) or not isinstance(recall, int | float) or not 0.0 <= recall <= 1.0:
        raise ToolkitRunError(f"expected a recall in [0, 1], got {recall!r}", file=path, field="recall")
    return float(recall)


def _read_errors(export: ToolkitExport, signs: list[str]) -> dict[tuple[int, int, int, int, int], list[float]]:
    """Raw errors per (scene, im, obj, est_id, gt_id) from the errors_*.json files (VSD: one value per tau folder)."""
    from bop_toolkit_lib import inout

    out: dict[tuple[int, int, int, int, int], list[float]] = {}
    for sign in signs:
        folder = export.eval_path / export.result_name / sign
        for path in sorted(folder.glob("errors_*.json")):
            for e in inout.load_json(str(path), keys_to_int=True):
                for gt_id, values in e["errors"].items():
                    key = (int(e["scene_id"]), int(e["im_id"]), int(e["obj_id"]), int(e["est_id"]), int(gt_id))
                    out.setdefault(key, []).extend(float(v) for v in values)
    return out


def result_summary(scores: ToolkitScores) -> dict[str, Any]:
    """The toolkit's average recalls under our score names (None where skipped)."""
    a = scores.average_recalls
    mssd, mspd = scores.recalls.get("mssd"), scores.recalls.get("mspd")
    return {
        "AR": a.get("bop19"),
        "AR_VSD": a.get("vsd"),
        "AR_MSSD": a.get("mssd"),
        "AR_MSPD": a.get("mspd"),
        "AR_MSPD<5px": None if mspd is None else mspd[0],
        "AR_MSSD<5%": None if mssd is None else mssd[0],
    }
