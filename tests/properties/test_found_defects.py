"""The inputs the property tests found broken, each pinned as a plain test (random draws may not meet it again)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from bop_cender.data.bop_io import as_number, image_size, load_image_dict, load_json, load_ply, save_ply
from bop_cender.data.models import load_models
from bop_cender.data.types import check_matrix
from bop_cender.errors import DatasetError, ResultsError
from bop_cender.results.bop_csv import read_bop_results
from bop_cender.results.convert_pvnet import convert_pvnet
from tests.data.dimo_builder import write_models


def test_a_utf8_bom_is_accepted_in_json_and_in_a_csv_without_header(tmp_path: Path) -> None:
    path = tmp_path / "scene_camera.json"
    path.write_bytes(b'\xef\xbb\xbf{"0": {"cam_K": [1, 0, 0, 0, 1, 0, 0, 0, 1]}}\r\n')
    assert load_json(path, keys_to_int=True) == {0: {"cam_K": [1, 0, 0, 0, 1, 0, 0, 0, 1]}}
    csv = tmp_path / "m_tless-test.csv"
    csv.write_bytes(b"\xef\xbb\xbf1,2,3,0.5,1 0 0 0 1 0 0 0 1,0 0 500,-1\n")
    (row,) = read_bop_results(csv)
    assert (row.scene_id, row.im_id, row.obj_id) == (1, 2, 3)


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("symmetries_discrete", 1.5, "symmetries_discrete: expected a list, got float"),
        ("symmetries_continuous", True, "symmetries_continuous: expected a list, got bool"),
        ("symmetries_discrete", [{}], r"symmetries_discrete\[0\]: expected 16 finite numbers"),
        ("symmetries_continuous", [{"axis": {}}], r"symmetries_continuous\[0\]: axis and offset must be 3 finite"),
        ("symmetries_discrete", [[0.0] * 16], r"symmetries_discrete\[0\]: expected a rigid transform"),
        ("symmetries_discrete", [[2.0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]], "expected a rigid transform"),
        ("symmetries_discrete", [[1.0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0]], "last row 0 0 0 1"),
        ("diameter", True, "1.diameter: expected a number, got True"),
    ],
)
def test_malformed_models_info_entries_are_one_dataset_error(tmp_path: Path, key: str, value, message: str) -> None:
    write_models(tmp_path, (1,))
    info_path = tmp_path / "models" / "models_info.json"
    info = json.loads(info_path.read_text())
    info["1"][key] = value
    info_path.write_text(json.dumps(info))
    with pytest.raises(DatasetError, match=message) as e:
        load_models(tmp_path / "models")
    assert e.value.file == str(info_path)


def test_a_truncated_ascii_ply_is_refused_by_the_loader(tmp_path: Path) -> None:
    path = tmp_path / "obj_000002.ply"
    save_ply(path, trimesh.creation.box(extents=(50.0, 30.0, 20.0)))
    data = path.read_bytes()
    path.write_bytes(data[: data.rindex(b"\n3 ", 0, len(data) - 90) + 8])  # inside the face list: 1 face of 12 left
    with pytest.raises(DatasetError, match="truncated: the file ends before face 1 of 12") as e:
        load_ply(path)
    assert e.value.file == str(path)


def test_a_bool_is_not_a_number() -> None:
    with pytest.raises(DatasetError, match="expected numbers of shape"):
        check_matrix([True, 0, 1, 0, 1, 1, 0, 0, 1], (9,), "0: cam_K", "scene_camera.json")
    with pytest.raises(DatasetError, match="expected a number, got False"):
        as_number(False, Path("scene_gt_info.json"), "0[0].visib_fract")
    assert check_matrix(np.eye(3).ravel().tolist(), (9,), "R").shape == (9,)  # numbers still pass


def test_a_pvnet_time_disagreement_names_the_json_and_key(tmp_path: Path) -> None:
    pose = np.c_[np.eye(3), [0, 0, 0.7]].tolist()
    source = tmp_path / "pvnet.json"
    source.write_text(json.dumps({"000001/000042": [{"obj_id": 5, "pose": pose, "time": 0.21},
                                                    {"obj_id": 2, "pose": pose, "time": 5.0}]}))  # fmt: skip
    out = tmp_path / "pvnet_tless-test.csv"
    with pytest.raises(ResultsError, match="time 5.0 s differs from 0.21 s at 000001/000042") as e:
        convert_pvnet(source, out)
    assert (e.value.file, e.value.field) == (str(source), "000001/000042[1].time")
    assert not out.exists()


@pytest.mark.parametrize("key", ["²", "--1", "٣"])
def test_a_key_that_only_looks_like_an_id_is_one_dataset_error(tmp_path: Path, key: str) -> None:
    path = tmp_path / "scene_gt_info.json"
    path.write_text(json.dumps({"0": [], key: []}))
    with pytest.raises(DatasetError, match="expected image ids") as e:
        load_image_dict(path)
    assert (e.value.file, e.value.field) == (str(path), repr(key))


def test_a_png_cut_inside_its_header_has_no_size(tmp_path: Path) -> None:
    import cv2

    path = tmp_path / "000000.png"
    path.write_bytes(cv2.imencode(".png", np.zeros((12, 16, 3), np.uint8))[1].tobytes()[:16])
    with pytest.raises(DatasetError, match="PNG header cut or malformed") as e:
        image_size(path)
    assert e.value.file == str(path)


@pytest.mark.parametrize(("key", "obj_id"), [("000001/000042", 1e30), ("000001/" + "9" * 19, 5)])
def test_a_pvnet_id_too_large_for_the_csv_is_refused(tmp_path: Path, key: str, obj_id: float) -> None:
    source = tmp_path / "pvnet.json"
    source.write_text(json.dumps({key: [{"obj_id": obj_id, "pose": np.c_[np.eye(3), [0, 0, 0.7]].tolist()}]}))
    out = tmp_path / "pvnet_tless-test.csv"
    with pytest.raises(ResultsError, match="is too large") as e:
        convert_pvnet(source, out)
    assert (e.value.file, e.value.field) == (str(source), f"{key}[0]")
    assert not out.exists()


@pytest.mark.parametrize(
    ("edit", "message"), [((0, 0, True), "expected numbers in a 3x4"), ((2, 3, 1e308), "not finite")]
)
def test_a_pvnet_pose_with_a_bool_or_a_translation_overflowing_mm_is_refused(tmp_path: Path, edit, message) -> None:
    pose = np.c_[np.eye(3), [0, 0, 0.7]].tolist()
    pose[edit[0]][edit[1]] = edit[2]
    source = tmp_path / "pvnet.json"
    source.write_text(json.dumps({"000001/000042": [{"obj_id": 5, "pose": pose}]}))
    out = tmp_path / "pvnet_tless-test.csv"
    with pytest.raises(ResultsError, match=message) as e:
        convert_pvnet(source, out)
    assert e.value.file == str(source) and e.value.field.startswith("000001/000042[0]")
    assert not out.exists()


def test_an_empty_npy_file_in_a_pvnet_folder_is_one_error(tmp_path: Path) -> None:
    """Found by the .npy folder property: np.load raised a bare EOFError on an empty file."""
    from bop_cender.errors import ResultsError
    from bop_cender.results.convert_pvnet import convert_pvnet

    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "000001_000003_000002.npy").write_bytes(b"")
    with pytest.raises(ResultsError, match="cannot read .npy") as e:
        convert_pvnet(tmp_path / "in", tmp_path / "pvnet_tless-test.csv")
    assert e.value.file.endswith("000001_000003_000002.npy")
    assert not (tmp_path / "pvnet_tless-test.csv").exists()
