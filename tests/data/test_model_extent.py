"""A mesh must be the size its models_info.json entry says: a mesh in metres scored every wrong pose right."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import pytest
import trimesh

from bop_cender.data.file_checks import check_meshes
from bop_cender.data.models import load_models
from bop_cender.errors import DatasetError, DatasetWarning
from bop_cender.eval.model_points import eval_vertices
from bop_cender.meshes import MeshCache


def _models_folder(root: Path, scale: float, binary: bool = False) -> Path:
    """A models folder with one 100 x 40 x 20 mm box (centred on the origin) whose PLY is scaled by ``scale``."""
    folder = root / "models"
    folder.mkdir(parents=True)
    box = trimesh.creation.box(extents=(100.0, 40.0, 20.0))
    box.apply_scale(scale)
    encoding = "binary" if binary else "ascii"
    (folder / "obj_000001.ply").write_bytes(trimesh.exchange.ply.export_ply(box, encoding=encoding))
    info = {"diameter": 109.5, "min_x": -50, "min_y": -20, "min_z": -10, "size_x": 100, "size_y": 40, "size_z": 20}
    (folder / "models_info.json").write_text(json.dumps({"1": info}))
    return folder


@pytest.mark.parametrize("binary", [False, True])
def test_a_mesh_of_its_entry_size_is_read(tmp_path: Path, binary: bool) -> None:
    models = load_models(_models_folder(tmp_path, 1.0, binary))
    assert eval_vertices(models[1]).shape == (8, 3)
    assert MeshCache(models).arrays(1).vertices.shape == (8, 3)
    assert check_meshes(models.values()) == (1, [])


@pytest.mark.parametrize("binary", [False, True])
def test_a_mesh_in_metres_is_refused_by_the_scorer_the_renderer_and_info(tmp_path: Path, binary: bool) -> None:
    models = load_models(_models_folder(tmp_path, 0.001, binary))  # the entry alone is fine
    expected = r"obj_000001.ply: models_info.json 1: min_x..size_z: the mesh's bounding box \(min -0.05, -0.02, -0.01"
    with pytest.raises(DatasetError, match=expected):
        eval_vertices(models[1])
    with pytest.raises(DatasetError, match=expected):
        MeshCache(models).arrays(1)
    checked, problems = check_meshes(models.values())
    assert checked == 1 and len(problems) == 1 and "other units, axes or origin than its entry" in problems[0]


def test_a_mesh_off_by_a_little_is_read_off_by_more_is_warned_of_and_in_other_units_refused(tmp_path: Path) -> None:
    folder = _models_folder(tmp_path, 1.0)
    info = json.loads((folder / "models_info.json").read_text())
    info["1"]["size_x"] = 104.0  # 4 % of the longest side: rounding, a resampled evaluation mesh
    (folder / "models_info.json").write_text(json.dumps(info))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert eval_vertices(load_models(folder)[1]).shape == (8, 3)
    info["1"]["min_y"] = -27.0  # 7 mm off: another maker's entry, read with a warning (a real download stays usable)
    (folder / "models_info.json").write_text(json.dumps(info))
    with pytest.warns(DatasetWarning, match="is not the one models_info.json gives object 1"):
        assert eval_vertices(load_models(folder)[1]).shape == (8, 3)
    models = load_models(_models_folder(tmp_path / "cm", 0.1))  # centimetres: refused
    with pytest.raises(DatasetError, match="a mesh in other units, axes or origin than its entry"):
        eval_vertices(models[1])
    models = load_models(_models_folder(tmp_path / "double", 2.5))
    with pytest.raises(DatasetError, match="a mesh in other units, axes or origin than its entry"):
        MeshCache(models).arrays(1)
    folder = _models_folder(tmp_path / "axes", 1.0)
    for edit in (
        {"size_x": 20, "size_z": 100, "min_x": -10, "min_z": -50},  # other axes: the longest sides agree
        {"min_x": -250, "min_y": -220, "min_z": -210},
    ):  # another origin: the entry's centre off the part
        (folder / "models_info.json").write_text(
            json.dumps({"1": {**info["1"], **edit, "min_y": edit.get("min_y", -20)}})
        )
        with pytest.raises(DatasetError, match="a mesh in other units, axes or origin than its entry"):
            eval_vertices(load_models(folder)[1])


def test_a_diameter_a_little_off_its_box_is_warned_of(tmp_path: Path) -> None:
    folder = _models_folder(tmp_path, 1.0)
    info = json.loads((folder / "models_info.json").read_text())
    info["1"]["diameter"] = 130.0  # beyond the diagonal (109.5) by 20 mm, under twice it
    (folder / "models_info.json").write_text(json.dumps(info))
    with pytest.warns(DatasetWarning, match=r"models_info.json: 1.diameter: diameter 130 mm does not fit"):
        load_models(folder)
