"""models_info entries and model folders: exact diameter and bbox, BOP files that load back unchanged."""

import json

import numpy as np
import pytest
import trimesh
from scipy.spatial.distance import pdist

from bop_cender.data.bop_io import load_ply
from bop_cender.data.dimo import CARRIER_MIN_ID
from bop_cender.data.models import load_models
from bop_cender.geometry.symmetry import symmetry_transforms
from bop_cender.synth.models_info import (
    models_info_entry,
    points_diameter,
    symmetry_deviation,
    write_model_folders,
    write_models,
)
from bop_cender.synth.parts import make_carrier, make_part_set, make_tube

INFO_KEYS = {"diameter", "min_x", "min_y", "min_z", "size_x", "size_y", "size_z"}


@pytest.fixture(scope="module")
def parts():
    rng = np.random.default_rng(11)
    objs = {i + 1: p for i, p in enumerate(make_part_set(rng, 6))}
    return objs | {CARRIER_MIN_ID: make_carrier(rng)}


def test_diameter_equals_brute_force_on_small_meshes():
    rng = np.random.default_rng(0)
    meshes = [trimesh.creation.icosphere(subdivisions=2, radius=7.0), trimesh.creation.box((30.0, 10.0, 4.0))]
    meshes.append(trimesh.Trimesh(rng.normal(size=(300, 3)) * [40.0, 10.0, 3.0], process=False))  # hull is a subset
    for mesh in meshes:
        brute = pdist(mesh.vertices).max()
        assert models_info_entry(mesh)["diameter"] == pytest.approx(brute, rel=1e-12)


def test_diameter_of_degenerate_point_sets():
    flat = np.c_[np.random.default_rng(1).uniform(-5, 5, size=(50, 2)), np.zeros(50)]  # coplanar: no 3D hull
    assert points_diameter(flat) == pytest.approx(pdist(flat).max(), rel=1e-12)
    assert points_diameter(np.array([[0.0, 0, 0], [3.0, 4.0, 0]])) == pytest.approx(5.0)
    assert points_diameter(np.zeros((1, 3))) == 0.0
    big = np.random.default_rng(2).normal(size=(3000, 3))
    assert points_diameter(big, chunk=256) == pytest.approx(pdist(big).max(), rel=1e-12)


def test_entry_bbox_and_symmetry_keys():
    tube = make_tube(np.random.default_rng(0), length=50.0, outer_diameter=30.0, wall=2.0)
    entry = models_info_entry(tube.mesh, tube.symmetries_discrete, tube.symmetries_continuous)
    np.testing.assert_allclose([entry[k] for k in ("min_x", "min_y", "min_z")], [-15.0, -15.0, -25.0], atol=1e-5)
    np.testing.assert_allclose([entry[k] for k in ("size_x", "size_y", "size_z")], [30.0, 30.0, 50.0], atol=1e-5)
    assert entry["diameter"] == pytest.approx(np.hypot(30.0, 50.0), abs=1e-4)
    assert entry["symmetries_continuous"] == [{"axis": [0.0, 0.0, 1.0], "offset": [0.0, 0.0, 0.0]}]
    assert entry["symmetries_discrete"] == [[1.0, 0, 0, 0, 0, -1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1]]
    plain = models_info_entry(tube.mesh)
    assert set(plain) == INFO_KEYS  # symmetry keys only when non-empty
    json.dumps(entry)  # plain Python types


def test_written_folder_loads_back_with_the_same_symmetries(tmp_path, parts):
    info = write_models(tmp_path / "models", parts)
    assert set(info) == set(parts)
    on_disk = json.loads((tmp_path / "models" / "models_info.json").read_text())
    assert set(on_disk) == {str(i) for i in parts}
    models = load_models(tmp_path / "models", is_target=lambda i: i < CARRIER_MIN_ID)
    assert set(models) == set(parts)
    for obj_id, part in parts.items():
        model = models[obj_id]
        assert model.is_target == (obj_id < CARRIER_MIN_ID)
        assert set(on_disk[str(obj_id)]) >= INFO_KEYS
        R_file, t_file = model.symmetry_transforms()
        R_part, t_part = symmetry_transforms(part.symmetries_discrete, part.symmetries_continuous)
        np.testing.assert_array_equal(R_file, R_part)
        np.testing.assert_array_equal(t_file, t_part)
        # The entry describes the PLY as stored (float32 text), which is the part to ~1e-5 mm.
        stored = load_ply(model.path)
        np.testing.assert_allclose(stored.vertices, part.mesh.vertices, atol=1e-4)
        assert model.diameter == pytest.approx(pdist(stored.vertices).max(), rel=1e-12)
        np.testing.assert_allclose(model.bbox_min, stored.vertices.min(axis=0), rtol=0, atol=1e-12)
        np.testing.assert_allclose(model.bbox_min + model.bbox_size, stored.vertices.max(axis=0), atol=1e-9)
        np.testing.assert_allclose(model.center, 0.0, atol=1e-4)  # BOP: origin at the bbox centre
        assert stored.is_watertight
        np.testing.assert_array_equal(stored.faces, part.mesh.faces)


def test_ply_is_ascii_with_vertex_normals(tmp_path, parts):
    write_models(tmp_path, {1: parts[1]})
    header = (tmp_path / "obj_000001.ply").read_text().split("end_header")[0]
    assert "format ascii" in header and "property float nx" in header


def test_written_symmetries_still_hold_for_the_stored_mesh(tmp_path, parts):
    write_models(tmp_path, parts)
    for obj_id, model in load_models(tmp_path).items():
        R, t = model.symmetry_transforms()
        idx = np.arange(0, len(R), 70)
        tol = 1e-3 * model.diameter
        assert symmetry_deviation(model.mesh, R[idx], t[idx], 2 * tol).max() <= tol, parts[obj_id].name


@pytest.mark.parametrize(
    ("layout", "folders"), [("dimo", ("models", "models_eval")), ("tless", ("models_cad", "models_eval"))]
)
def test_model_folders_per_layout(tmp_path, parts, layout, folders):
    written = write_model_folders(tmp_path, parts, layout)
    assert tuple(written) == folders
    main, evl = (tmp_path / f for f in folders)
    for name in ["models_info.json", *(f"obj_{i:06d}.ply" for i in parts)]:
        assert (main / name).read_bytes() == (evl / name).read_bytes()  # eval copy identical (no resampling)
    assert (tmp_path / "models" / "construction").is_dir() == (layout == "dimo")
    assert not any(p.name.startswith(".") for p in main.iterdir())  # no temporary files left
    assert set(load_models(evl)) == set(parts)


def test_unknown_layout_is_rejected(tmp_path, parts):
    with pytest.raises(ValueError, match="layout"):
        write_model_folders(tmp_path, parts, "ycbv")


def test_symmetry_deviation_is_zero_for_identity_and_inf_beyond_the_radius():
    box = trimesh.creation.box((40.0, 20.0, 10.0))
    eye, zero = np.eye(3)[None], np.zeros((1, 3))
    assert symmetry_deviation(box, eye, zero, 0.1)[0] == pytest.approx(0.0, abs=1e-12)
    shift = np.array([[0.05, 0.0, 0.0]])  # within the search radius: the distance is reported
    assert symmetry_deviation(box, eye, shift, 0.1)[0] == pytest.approx(0.05, abs=1e-9)
    assert symmetry_deviation(box, eye, shift * 10, 0.1)[0] == np.inf


def test_a_run_cut_off_between_the_model_folders_is_finished_by_the_next(tmp_path, parts):
    import shutil

    write_model_folders(tmp_path, parts, "tless")
    info = tmp_path / "models_cad" / "models_info.json"
    stamp = info.stat().st_mtime_ns
    shutil.rmtree(tmp_path / "models_eval")  # as if the first run stopped after models_cad/
    write_model_folders(tmp_path, parts, "tless")
    assert (tmp_path / "models_eval" / "models_info.json").is_file()
    assert info.stat().st_mtime_ns == stamp  # the complete folder is kept as it is
