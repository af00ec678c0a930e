import json
import re

import numpy as np
import pytest
import trimesh

from bop_cender.data.bop_io import (
    as_int,
    atomic_path,
    dumps_bop_json,
    image_size,
    load_depth,
    load_json,
    load_mask,
    load_ply,
    load_rgb,
    require_dir,
    require_file,
    save_depth,
    save_json,
    save_ply,
    write_image,
    write_text_atomic,
    write_texts_atomic,
)
from bop_cender.errors import DatasetError


def test_json_keys_to_int_and_round_trip(tmp_path):
    content = {"10": [1, 2], "2": {"a": 1.5}, "name": "x"}
    save_json(tmp_path / "a.json", content)
    text = (tmp_path / "a.json").read_text()
    # Digit keys sorted numerically, one entry per line, as the BOP toolkit writes.
    assert text.index('"2"') < text.index('"10"')
    assert json.loads(text) == content
    loaded = load_json(tmp_path / "a.json", keys_to_int=True)
    assert loaded == {2: {"a": 1.5}, 10: [1, 2], "name": "x"}


def test_json_list_of_dicts_one_per_line():
    text = dumps_bop_json([{"b": 1, "a": 2}, {"a": 3}])
    assert text.splitlines()[1].strip() == '{"a": 2, "b": 1},'


def test_json_errors_name_file_and_position(tmp_path):
    with pytest.raises(DatasetError, match="missing.json: file not found"):
        load_json(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text('{"0": [1, 2,\n]}')
    with pytest.raises(DatasetError, match=r"bad.json: malformed JSON: .* line 2, column 1"):
        load_json(tmp_path / "bad.json")


@pytest.mark.parametrize(
    ("text", "keys_to_int", "key"),
    [('{"a": 1, "a": 2}', False, "a"), ('{"0": {"x": 1, "x": 1}}', True, "x"), ('{"1": [], "01": []}', True, "1")],
)
def test_a_repeated_json_key_is_refused_not_dropped(tmp_path, text, keys_to_int, key):
    (tmp_path / "dup.json").write_text(text)
    with pytest.raises(DatasetError, match=f"dup.json: {key}: a JSON object repeats the key") as info:
        load_json(tmp_path / "dup.json", keys_to_int=keys_to_int)
    assert info.value.field == key
    (tmp_path / "ok.json").write_text('{"a": {"a": 1}, "b": {"a": 2}}')  # one key per object is fine
    assert load_json(tmp_path / "ok.json") == {"a": {"a": 1}, "b": {"a": 2}}


def test_atomic_path_leaves_nothing_on_error(tmp_path):
    target = tmp_path / "out.txt"
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("boom")
    assert not target.exists()
    assert list(tmp_path.iterdir()) == []


def test_atomic_path_names_the_target_not_its_temporary_file(tmp_path):
    (tmp_path / "out.txt").mkdir()  # the rename onto the target fails
    with pytest.raises(IsADirectoryError) as info:
        write_text_atomic(tmp_path / "out.txt", "x")
    assert info.value.filename == str(tmp_path / "out.txt")
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_files_written_as_a_unit_are_all_or_none(tmp_path):
    a, b = tmp_path / "a.csv", tmp_path / "b.json"
    write_texts_atomic({a: "new a", b: "new b"})
    assert (a.read_text(), b.read_text()) == ("new a", "new b")
    c = tmp_path / "c.json"
    c.mkdir()  # cannot be replaced: a, written first, is put back as it was
    with pytest.raises(IsADirectoryError) as info:
        write_texts_atomic({a: "newer a", c: "c"})
    assert info.value.filename == str(c) and a.read_text() == "new a"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "b.json", "c.json"]


def test_require_file_and_dir_say_what_is_there_instead(tmp_path):
    (tmp_path / "f").write_text("x")
    assert require_file(tmp_path / "f", "results file") == tmp_path / "f"
    with pytest.raises(DatasetError, match="is a directory, expected a results file"):
        require_file(tmp_path, "results file")
    with pytest.raises(DatasetError, match="nope: results file not found"):
        require_file(tmp_path / "nope", "results file")
    with pytest.raises(DatasetError, match="f: is a file, expected a dataset root folder"):
        require_dir(tmp_path / "f", "dataset root folder")
    with pytest.raises(DatasetError, match="nope: dataset root folder not found"):
        require_dir(tmp_path / "nope", "dataset root folder")


def test_depth_round_trip(tmp_path):
    depth = np.array([[0.0, 600.1], [812.3, 6553.5]], dtype=np.float32)
    save_depth(tmp_path / "d.png", depth, 0.1)
    back = load_depth(tmp_path / "d.png", 0.1)
    assert back.dtype == np.float32
    np.testing.assert_allclose(back, depth, atol=0.05)
    assert back[0, 0] == 0
    with pytest.raises(ValueError, match="uint16"):
        save_depth(tmp_path / "e.png", np.array([[7000.0]]), 0.1)


def test_rgb_mask_and_size(tmp_path):
    rgb = np.zeros((5, 7, 3), np.uint8)
    rgb[..., 0] = 200  # red
    write_image(tmp_path / "c.png", rgb)
    np.testing.assert_array_equal(load_rgb(tmp_path / "c.png"), rgb)
    assert image_size(tmp_path / "c.png") == (7, 5)
    write_image(tmp_path / "c.jpg", rgb)
    assert image_size(tmp_path / "c.jpg") == (7, 5)
    mask = np.zeros((5, 7), np.uint8)
    mask[1:3, 2:4] = 255
    write_image(tmp_path / "m.png", mask)
    assert load_mask(tmp_path / "m.png").sum() == 4
    with pytest.raises(DatasetError, match="image not found"):
        load_mask(tmp_path / "nope.png")
    (tmp_path / "junk.png").write_bytes(b"not a png")
    with pytest.raises(DatasetError, match="cannot decode"):
        load_rgb(tmp_path / "junk.png")


def test_ply_round_trip_keeps_vertices(tmp_path):
    mesh = trimesh.creation.box(extents=(10.0, 20.0, 30.0))
    save_ply(tmp_path / "obj_000001.ply", mesh)
    back = load_ply(tmp_path / "obj_000001.ply")
    np.testing.assert_allclose(back.vertices, mesh.vertices)
    np.testing.assert_array_equal(back.faces, mesh.faces)
    header = (tmp_path / "obj_000001.ply").read_text().split("end_header")[0]
    assert "property float nx" in header or "property double nx" in header


def test_ply_errors(tmp_path):
    with pytest.raises(DatasetError, match="model file not found"):
        load_ply(tmp_path / "obj_000009.ply")
    (tmp_path / "bad.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n")
    with pytest.raises(DatasetError, match="bad.ply"):
        load_ply(tmp_path / "bad.ply")


def test_json_that_is_not_utf8_or_not_a_file_is_one_error(tmp_path):
    (tmp_path / "latin.json").write_bytes(b'{"name": "caf\xe9"}')
    with pytest.raises(DatasetError, match="not UTF-8 text"):
        load_json(tmp_path / "latin.json")
    (tmp_path / "folder.json").mkdir()
    with pytest.raises(DatasetError, match="folder.json: is a directory, expected a file"):
        load_json(tmp_path / "folder.json")


def test_as_int_refuses_nan_infinity_bool_and_fractions():
    assert as_int(3, "f.json", "k") == 3 and as_int(3.0, "f.json", "k") == 3
    assert as_int(" 7 ", "f.json", "k", strings=True) == 7
    for bad in (float("nan"), float("inf"), True, 2.5, "7", None):
        with pytest.raises(DatasetError, match="k: expected an integer"):
            as_int(bad, "f.json", "k")


def test_atomic_writes_get_the_permissions_of_a_plain_write(tmp_path):
    save_json(tmp_path / "a.json", {"x": 1})
    (tmp_path / "plain.json").write_text("{}")
    assert (tmp_path / "a.json").stat().st_mode & 0o777 == (tmp_path / "plain.json").stat().st_mode & 0o777


def test_save_depth_refuses_what_uint16_cannot_hold(tmp_path):
    for bad in ([[-1.0, 0.0]], [[np.nan, 0.0]], [[7000.0, 0.0]]):
        with pytest.raises(ValueError, match="depth must be finite and within"):
            save_depth(tmp_path / "d.png", np.asarray(bad), 0.1)
    assert not (tmp_path / "d.png").exists()


def test_differing_image_ids_name_the_file_and_a_few_ids(tmp_path):
    from bop_cender.data.bop_io import check_same_image_ids

    check_same_image_ids({tmp_path / "a.json": [0, 1, 2], tmp_path / "b.json": [2, 1, 0]})
    with pytest.raises(
        DatasetError, match=r"b.json: image ids: .*missing 0, 1, 2, 3, 4, 5, 6, 7, \.\.\. \(40 in all\)"
    ):
        check_same_image_ids({tmp_path / "a.json": range(50), tmp_path / "b.json": range(40, 50)})


@pytest.mark.parametrize("binary", [False, True], ids=["ascii", "binary"])
def test_every_model_reader_checks_the_same_things(tmp_path, binary):
    """load_ply (trimesh, binary or ASCII) and the scorer's ASCII reader refuse the same broken meshes."""
    from bop_cender.data.ply_ascii import ascii_mesh

    def write(name, vertices, faces):
        mesh = trimesh.Trimesh(vertices, faces, process=False, validate=False)
        path = tmp_path / f"{name}.ply"
        path.write_bytes(trimesh.exchange.ply.export_ply(mesh, encoding="binary" if binary else "ascii"))
        return path

    box = trimesh.creation.box()
    nan = np.array(box.vertices)
    nan[3, 1] = np.nan
    cases = {
        "nan": (write("nan", nan, box.faces), "vertex: 1 vertex coordinate(s) NaN or infinite (first: vertex 3)"),
        "out": (write("out", box.vertices, np.vstack([box.faces, [[0, 1, 8]]])), "index vertices outside 0..7"),
    }
    for path, message in cases.values():
        with pytest.raises(DatasetError, match=re.escape(message)):
            load_ply(path)
        if not binary:
            with pytest.raises(DatasetError, match=re.escape(message)):
                ascii_mesh(path)


def test_quiet_stderr_silences_fd_2_and_restores_it_after_nested_and_threaded_use(capfd):
    import os
    from concurrent.futures import ThreadPoolExecutor

    from bop_cender.data.bop_io import quiet_stderr

    def inside(k):
        with quiet_stderr(), quiet_stderr():
            os.write(2, f"hidden {k}\n".encode())

    with ThreadPoolExecutor(4) as pool:
        list(pool.map(inside, range(16)))
    os.write(2, b"shown\n")
    assert capfd.readouterr().err == "shown\n"


def test_a_cut_json_string_says_where_once(tmp_path) -> None:
    """json's message "Unterminated string starting at" was followed by our " at line ...": "at at"."""
    from bop_cender.data.bop_io import load_json

    path = tmp_path / "scene_gt.json"
    path.write_text('{"0": [{"obj_id": "ab')
    with pytest.raises(DatasetError, match=r"malformed JSON: Unterminated string starting at line 1, column 19$"):
        load_json(path)
