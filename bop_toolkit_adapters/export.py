"""Export a dataset split and a results file so the official BOP toolkit evaluates them unchanged.

The toolkit reads ``<datasets_path>/<dataset>/`` in the BOP layout, with int scene folders
``{scene_id:06d}``, a ``test_targets_bop19.json``, ``scene_gt_info.json`` (visible fractions) and a
``models_eval/`` folder, and results named ``{method}_{dataset}-{split}[-{split_type}].csv``. This
module writes exactly that under one output folder, from the same ground truth our scorer uses:

- ``datasets/<dataset>/<split folder>/<scene:06d>/``: ``scene_camera.json``, ``scene_gt.json``,
  ``scene_gt_info.json`` holding the entries of the selected images as stored in the source files
  (DIMO's suffixed folder ``000123_17`` becomes ``012317``, its BOP int id); ``scene_gt_info.json``
  is written from our rendered visible fractions where the source has none (DIMO); ``depth/`` links
  to the source depth images;
- ``datasets/<dataset>/models_eval`` links to the evaluation models (DIMO: ``models/``);
- ``datasets/<dataset>/test_targets_bop19.json``: the targets our scorer uses (for DIMO computed
  by the visibility rule, see :mod:`bop_cender.eval.targets`);
- ``results/<toolkit result name>.csv``: a copy of the results file.

Datasets the toolkit does not know (DIMO, any custom name) are registered at run time by
:mod:`bop_toolkit_adapters.runtime`; nothing of the toolkit is edited.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from bop_cender.data.bop_io import load_json, save_json
from bop_cender.data.layout import SCENE_CAMERA, SCENE_GT, SCENE_GT_INFO, TARGETS_FILE
from bop_cender.data.targets_file import write_targets
from bop_cender.data.types import Dataset
from bop_cender.errors import ResultsError
from bop_cender.eval.ground_truth import GroundTruth, collect_ground_truth
from bop_cender.eval.targets import resolve_targets
from bop_cender.eval.toolkit_constants import TOOLKIT_TEST_WIDTHS, mspd_width, vsd_delta_for
from bop_cender.eval.visibility import rendered_visib_fracts
from bop_cender.meshes import MeshCache
from bop_cender.results.files import parse_result_filename, result_filename

#: Split folder the toolkit uses for (dataset, split) when no split type is given (dataset_params.py).
TOOLKIT_DEFAULT_SPLIT_TYPE = {("tless", "test"): "primesense", ("tless", "train"): "primesense"}


@dataclass(frozen=True)
class ToolkitExport:
    """Where an export is and what the toolkit must be told about it.

    Attributes:
        out_dir: the export root; datasets_path, results_path, eval_path: the toolkit's three folders.
        dataset, split, split_type: as in the result file name; split_folder: the folder under the dataset.
        result_filename: the results CSV's name under ``results_path``.
        obj_ids: object ids with an evaluation model. scene_ids: exported scene ids.
        im_size: ``(width, height)`` of the images (the toolkit renders VSD at this size).
        mspd_width: image width MSPD is normalised with (the toolkit's constant where it has one).
        vsd_delta: VSD delta (mm), None without depth. known_to_toolkit: dataset_params knows the name.
        targets_note: how the targets were made.
    """

    out_dir: Path
    datasets_path: Path
    results_path: Path
    eval_path: Path
    dataset: str
    split: str
    split_type: str | None
    split_folder: str
    result_filename: str
    obj_ids: tuple[int, ...]
    scene_ids: tuple[int, ...]
    im_size: tuple[int, int]
    mspd_width: int
    vsd_delta: float | None
    known_to_toolkit: bool
    targets_note: str

    @property
    def result_name(self) -> str:
        return self.result_filename.split(".")[0]


def export_for_toolkit(
    dataset: Dataset,
    results_csv: str | Path,
    out_dir: str | Path,
    *,
    method: str | None = None,
    vsd_delta: float | None = None,
    progress: bool = True,
) -> ToolkitExport:
    """Write the toolkit's view of ``dataset`` and ``results_csv`` under ``out_dir`` (see the module docstring).

    Args:
        dataset: the split the results were made on (as opened for scoring).
        results_csv: the results file.
        out_dir: export root (created; an existing export there is replaced).
        method: method name for the toolkit's file name (default: from the results file name).
        vsd_delta: VSD delta to register for a dataset the toolkit does not know (default 15 mm).
    """
    out_dir = Path(out_dir)
    results_csv = Path(results_csv)
    gt = collect_ground_truth(dataset, progress)
    meshes = MeshCache(dataset.eval_models or dataset.models)
    targets = resolve_targets(
        dataset.bop19_targets(), gt, dataset.target_obj_ids, lambda: rendered_visib_fracts(list(gt), meshes, progress)
    )
    # The toolkit knows no DIMO: it is registered with the user's split names (real, sim); BOP datasets keep their
    # split folder, whose suffix is the split type (test_primesense).
    split_folder = dataset.split if dataset.name == "dimo" else dataset.split_folder
    split, split_type = _toolkit_split(dataset.name, split_folder)
    method = method or _method(results_csv)
    name = result_filename(method, dataset.name, split, split_type)

    base = out_dir / "datasets" / dataset.name
    if base.exists():
        shutil.rmtree(base)
    scene_ids = _export_scenes(gt, base / split_folder, targets.visib)
    write_targets(base / TARGETS_FILE, targets.targets)
    models_dir = Path(next(iter((dataset.eval_models or dataset.models).values())).path).parent
    _link(models_dir.resolve(), base / "models_eval")
    results_path = out_dir / "results"
    results_path.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(results_csv, results_path / name)
    (out_dir / "eval").mkdir(parents=True, exist_ok=True)

    first = next(iter(gt))
    has_depth = all(im.depth_path is not None for im in gt)
    return ToolkitExport(
        out_dir=out_dir,
        datasets_path=out_dir / "datasets",
        results_path=results_path,
        eval_path=out_dir / "eval",
        dataset=dataset.name,
        split=split,
        split_type=split_type,
        split_folder=split_folder,
        result_filename=name,
        obj_ids=tuple(sorted(load_json(models_dir / "models_info.json", keys_to_int=True))),
        scene_ids=tuple(scene_ids),
        im_size=(first.width, first.height),
        mspd_width=int(mspd_width(dataset.name, split_folder, first.width).value),
        vsd_delta=vsd_delta_for(dataset.name, vsd_delta).value if has_depth else None,
        known_to_toolkit=dataset.name in TOOLKIT_TEST_WIDTHS,
        targets_note=targets.note,
    )


def _export_scenes(gt: GroundTruth, split_dir: Path, visib: dict) -> list[int]:
    """Per scene folder, the selected images' entries of the three JSON files, and links to their depth."""
    by_scene: dict[int, list] = {}
    for image in gt:
        by_scene.setdefault(image.scene_int, []).append(image)
    for scene_int, images in by_scene.items():
        src = images[0].scene_dir
        if src is None:
            raise ValueError(f"scene {images[0].scene_id} has no folder on disk: cannot export it for the toolkit")
        camera = load_json(src / SCENE_CAMERA, keys_to_int=True)
        scene_gt = load_json(src / SCENE_GT, keys_to_int=True)
        info_path = src / SCENE_GT_INFO
        info = load_json(info_path, keys_to_int=True) if info_path.is_file() else None
        dst = split_dir / f"{scene_int:06d}"
        ims = sorted(im.im_id for im in images)
        save_json(dst / SCENE_CAMERA, {im: camera[im] for im in ims})
        save_json(dst / SCENE_GT, {im: scene_gt[im] for im in ims})
        if info is not None:
            save_json(dst / SCENE_GT_INFO, {im: info[im] for im in ims})
        else:
            fracts = {im.im_id: visib[im.key] for im in images}
            save_json(
                dst / SCENE_GT_INFO,
                {im: [{"visib_fract": fracts[im].get(g, 0.0)} for g in range(len(scene_gt[im]))] for im in ims},
            )
        for image in images:
            if image.depth_path is not None:
                _link(Path(image.depth_path).resolve(), dst / "depth" / f"{image.im_id:06d}.png")
    return sorted(by_scene)


def _toolkit_split(name: str, folder: str) -> tuple[str, str | None]:
    """(split, split_type) for the result file name, such that the toolkit resolves ``folder`` again."""
    split, _, split_type = folder.partition("_")
    if not split_type:
        return split, None
    if TOOLKIT_DEFAULT_SPLIT_TYPE.get((name, split)) == split_type:
        return split, None  # the toolkit adds it back (tless-test -> test_primesense)
    return split, split_type


def _method(results_csv: Path) -> str:
    try:
        return parse_result_filename(results_csv.name).method
    except ResultsError:  # not a BOP name: the toolkit still needs one
        return "method"


def _link(src: Path, dst: Path) -> None:
    """Symlink ``dst -> src`` (copy where links are not allowed)."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    if dst.is_symlink() or dst.exists():
        dst.unlink() if not dst.is_dir() or dst.is_symlink() else shutil.rmtree(dst)
    try:
        os.symlink(src, dst, target_is_directory=src.is_dir())
    except OSError:
        shutil.copytree(src, dst) if src.is_dir() else shutil.copyfile(src, dst)
