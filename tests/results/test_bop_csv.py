"""BOP results CSV: real submissions, exact round trips, world -> camera rows, every kind of bad line."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bop_cender.data.scene_ids import int_to_scene_folder
from bop_cender.data.types import CameraView, GtObject, Scene
from bop_cender.errors import ConfigError, ResultsError, ResultsWarning
from bop_cender.estimates import ObjectEstimate, SceneEstimate
from bop_cender.geometry.poses import invert_pose, make_pose
from bop_cender.results import bop_csv as results
from bop_cender.results.bop_csv import (
    HEADER,
    BopEstimate,
    ResultName,
    group_by_image,
    parse_result_filename,
    read_bop_results,
    read_run_sidecar,
    result_filename,
    scene_estimates_to_rows,
    write_bop_results,
    write_run_sidecar,
)

SAMPLES = Path(__file__).parents[2].parent / "shared/reference/bop_results_samples"
R30 = "0.8660254037844387 -0.5 0.0 0.5 0.8660254037844387 0.0 0.0 0.0 1.0"  # 30 degrees about z
GOOD = f"1,0,2,0.93,{R30},12.3 -45.6 720.1,0.31"


def _random_rows(n: int, seed: int = 0) -> list[BopEstimate]:
    rng = np.random.default_rng(seed)
    Rs = Rotation.random(n, random_state=rng).as_matrix()
    rows = []
    for k in range(n):
        scene, im = int(rng.integers(0, 3)), int(rng.integers(0, 4))
        rows.append(BopEstimate(scene, im, int(rng.integers(1, 31)), rng.random() / 3, Rs[k], rng.normal(0, 300, 3),
                                (scene * 10 + im) / 7))  # fmt: skip
    return rows


def _write(tmp_path: Path, *lines: str, name: str = "m_tless-test.csv", end: str = "") -> Path:
    path = tmp_path / name
    path.write_text("\n".join(lines) + end, encoding="utf-8")
    return path


def _problems(path: Path, **kwargs) -> list[str]:
    with pytest.raises(ResultsError) as info:
        read_bop_results(path, **kwargs)
    assert str(path) in str(info.value)
    return info.value.problems


# --- real submission ----------------------------------------------------------------------------


def test_reads_real_submission_unchanged() -> None:
    files = sorted(SAMPLES.glob("*.csv"))
    if not files:
        pytest.skip(f"the BOP sample submission is not at {SAMPLES}")
    raw = files[0].read_text()
    assert not raw.endswith("\n")  # the property under test: no final newline
    with warnings.catch_warnings():
        warnings.simplefilter("error", ResultsWarning)
        rows = read_bop_results(files[0])
    assert len(rows) == 1645
    assert rows[0].line == 2 and rows[-1].line == 1646
    last = raw.rsplit("\n", 1)[1].split(",")
    assert rows[-1].score == float(last[3]) and rows[-1].time == float(last[6])
    assert np.array_equal(rows[-1].t, [float(x) for x in last[5].split()])
    for group in group_by_image(rows).values():
        assert len({r.time for r in group}) == 1
    name = parse_result_filename(files[0])
    assert (name.method, name.dataset, name.split, name.split_type) == ("cnos-fastsammegapose", "lmo", "test", None)
    assert name.optional_id == files[0].stem.split("_", 2)[2]


# --- writer and round trips ---------------------------------------------------------------------


def test_round_trip_is_exact(tmp_path: Path) -> None:
    rows = _random_rows(60)
    rows.append(BopEstimate(5, 0, 1, 0.1 + 0.2, np.eye(3), [-0.0, 1e-300, 5e300], -1))
    path = tmp_path / "cendernet_tless-test.csv"
    write_bop_results(path, rows, sort=False)
    back = read_bop_results(path)
    assert back == rows  # bit for bit (BopEstimate equality compares exact values)
    assert [r.line for r in back] == list(range(2, len(rows) + 2))
    assert path.read_text().splitlines()[0] == HEADER
    assert np.signbit(back[-1].t[0])  # even -0.0 survives


def test_equality_sees_one_ulp() -> None:
    a = _random_rows(1)[0]
    b = BopEstimate(a.scene_id, a.im_id, a.obj_id, a.score, a.R, np.nextafter(a.t, np.inf), a.time, line=7)
    assert a != b
    assert a == BopEstimate(a.scene_id, a.im_id, a.obj_id, a.score, a.R, a.t, a.time, line=7)


def test_writer_sorts_by_image_then_score(tmp_path: Path) -> None:
    rows = _random_rows(40, seed=1)
    path = tmp_path / "m_tless-test.csv"
    write_bop_results(path, rows)
    back = read_bop_results(path)
    assert sorted(back, key=lambda r: (r.scene_id, r.im_id, -r.score)) == back
    assert sorted(map(_key, back)) == sorted(map(_key, rows))


def _key(r: BopEstimate) -> tuple:
    return (r.scene_id, r.im_id, r.obj_id, r.score, r.time, r.R.tobytes(), r.t.tobytes())


def _scene(scene_id: str, n_views: int = 3) -> Scene:
    rng = np.random.default_rng(5)
    K = np.array([[600.0, 0, 160], [0, 600.0, 128], [0, 0, 1]])
    views = tuple(
        CameraView(im_id=2 * k, K=K, width=320, height=256,
                   T_cam_world=make_pose(Rotation.random(random_state=rng).as_matrix(), [0, 0, 700 + 10 * k]))
        for k in range(n_views)
    )  # fmt: skip
    gt = tuple(
        GtObject(obj_id, make_pose(Rotation.random(random_state=rng).as_matrix(), rng.normal(0, 80, 3)))
        for obj_id in (4, 1)
    )
    return Scene("dimo", "sim", scene_id, views, gt)


def _estimate_from_gt(scene: Scene, time_s: float = 2.5) -> SceneEstimate:
    objs = [ObjectEstimate(g.obj_id, g.T_world_model, 1.0 - 0.1 * k) for k, g in enumerate(scene.gt)]
    return SceneEstimate(scene.key, scene.scene_id, tuple(objs), time_s)


@pytest.mark.parametrize("scene_id, expected", [("000123_17", 12317), ("000007", 7)])
def test_world_to_camera_to_world(tmp_path: Path, scene_id: str, expected: int) -> None:
    scene = _scene(scene_id)
    rows = scene_estimates_to_rows(scene, _estimate_from_gt(scene))
    assert len(rows) == 6
    path = tmp_path / "cendernet_dimo-sim.csv"
    write_bop_results(path, rows)
    assert all(line.startswith(f"{expected},") for line in path.read_text().splitlines()[1:])
    back = read_bop_results(path)
    assert len(back) == 6
    for row in back:
        assert row.scene_id == expected and int_to_scene_folder(row.scene_id, "_" in scene_id) == scene_id
        assert row.time == 2.5
        view = scene.view(row.im_id)
        gt = next(g for g in scene.gt if g.obj_id == row.obj_id)
        T_cam_model = view.T_cam_world @ gt.T_world_model
        assert np.array_equal(row.R, T_cam_model[:3, :3]) and np.array_equal(row.t, T_cam_model[:3, 3])
        np.testing.assert_allclose(invert_pose(view.T_cam_world) @ row.T_cam_model, gt.T_world_model, atol=1e-9)
    assert {(r.im_id, r.obj_id) for r in back} == {(v.im_id, g.obj_id) for v in scene.views for g in scene.gt}


def test_rows_refuse_estimate_of_another_scene() -> None:
    with pytest.raises(ValueError, match="given with scene"):
        scene_estimates_to_rows(_scene("000001"), _estimate_from_gt(_scene("000002")))


def test_writer_rejects_bad_rows_and_names(tmp_path: Path) -> None:
    rows = _random_rows(3)
    bad = BopEstimate(1, 0, 2, np.nan, np.eye(3), [0, 0, 1], 0.1)
    with pytest.raises(ResultsError) as info:
        write_bop_results(tmp_path / "m_tless-test.csv", [*rows, bad])
    assert info.value.problems == ["row 3: score: expected finite numbers, found NaN or inf"]
    for name in ("my_method_tless-test.csv", "method_tless.csv", "m_tless-test.txt"):
        with pytest.raises(ResultsError, match="file name"):
            write_bop_results(tmp_path / name, rows)
    assert list(tmp_path.iterdir()) == []
    slightly = BopEstimate(1, 0, 2, 0.5, np.diag([1.0, 1.0, 1.001]), [0, 0, 1], 0.1)
    with pytest.warns(ResultsWarning, match="1 rotation.* at row 3"):
        write_bop_results(tmp_path / "warn_tless-test.csv", [*rows, slightly])
    (tmp_path / "warn_tless-test.csv").unlink()
    write_bop_results(tmp_path / "anything.csv", rows, strict_name=False)
    assert read_bop_results(tmp_path / "anything.csv") == sorted(rows, key=lambda r: (r.scene_id, r.im_id, -r.score))


def test_atomic_write_keeps_old_file_on_failure(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "m_tless-test.csv"
    write_bop_results(path, _random_rows(5))
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no temp file left behind
    before = path.read_bytes()
    calls = []
    real = results._format_row

    def failing(row: BopEstimate) -> str:
        calls.append(row)
        if len(calls) == 3:
            raise RuntimeError("disk full")
        return real(row)

    monkeypatch.setattr(results, "_format_row", failing)
    with pytest.raises(RuntimeError, match="disk full"):
        write_bop_results(path, _random_rows(10, seed=3))
    assert len(calls) == 3  # it failed mid-write
    assert path.read_bytes() == before
    calls.clear()
    with pytest.raises(RuntimeError, match="disk full"):
        write_bop_results(tmp_path / "new_tless-test.csv", _random_rows(10, seed=3))
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no partial new file, no temp files


# --- reader: accepted variants ------------------------------------------------------------------


def test_reader_accepts_crlf_trailing_blank_lines_and_no_header(tmp_path: Path) -> None:
    crlf = tmp_path / "crlf.csv"
    crlf.write_bytes(("\r\n".join([HEADER, GOOD, GOOD.replace("1,0,2", "1,0,3")]) + "\r\n\r\n  \r\n").encode())
    rows = read_bop_results(crlf)
    assert [r.obj_id for r in rows] == [2, 3] and rows[0].line == 2
    assert np.array_equal(rows[0].t, [12.3, -45.6, 720.1]) and rows[0].time == 0.31
    no_header = read_bop_results(_write(tmp_path, GOOD, name="noheader.csv"))
    assert no_header[0].line == 1 and no_header == rows[:1]
    assert read_bop_results(_write(tmp_path, HEADER, name="empty.csv")) == []


def test_unknown_times_are_skipped_as_the_toolkit_skips_them(tmp_path: Path) -> None:
    """The toolkit's check_consistent_timings (thodan/bop_toolkit @ cea62d6) skips negative (unknown) times: a -1
    beside 0.31 in one image passes it (the average time is then unknown); two known times 0.01 s apart fail it."""
    rows = read_bop_results(
        _write(
            tmp_path,
            HEADER,
            GOOD,
            GOOD.replace("1,0,2,", "1,0,4,").replace(",0.31", ",0.3105"),
            GOOD.replace("1,0,2,", "1,0,3,").replace(",0.31", ",-1"),
            GOOD.replace("1,0,2,", "1,1,2,").replace(",0.31", ",-5"),
        )  # fmt: skip
    )
    assert [r.time for r in rows] == [0.31, 0.3105, -1.0, -5.0]  # any negative time is unknown, as in the toolkit
    problems = _problems(_write(tmp_path, HEADER, GOOD, GOOD.replace("1,0,2,", "1,0,3,").replace(",0.31", ",0.32"),
                                name="mixed_tless-test.csv"))  # fmt: skip
    assert problems == ["line 3: time: 0.32 s differs from 0.31 s of the same image (scene 1, image 0) at line 2;"
                        " one image's estimates must share its time within 0.001 s"]  # fmt: skip
    unchecked = read_bop_results(tmp_path / "mixed_tless-test.csv", check_times=False)  # BOP'24 checks after its cap
    assert [r.time for r in unchecked] == [0.31, 0.32]


# --- reader: bad input --------------------------------------------------------------------------


@pytest.mark.parametrize(
    "line, message",
    [
        (GOOD.replace("0.5 0.866", "nan 0.866"), "R: expected finite numbers, found NaN or inf"),
        (GOOD.replace("720.1", "inf"), "t: expected finite numbers, found NaN or inf"),
        (GOOD + ",extra", "expected 7 comma-separated fields, got 8"),
        (GOOD.replace("1,0,2,", "1,0,2.0,"), "obj_id: expected a non-negative integer, got '2.0'"),
        (GOOD.replace("1,0,2,", "1,-3,2,"), "im_id: expected a non-negative integer, got '-3'"),
        (GOOD.replace("1,0,2,", "x,0,2,"), "scene_id: expected a non-negative integer"),
        (GOOD.replace(" 0.0 1.0,", " 1.0,"), "R: expected 9 number(s), got 8"),
        (GOOD.replace("12.3 -45.6", "12.3"), "t: expected 3 number(s), got 2"),
        (GOOD.replace("0.93", "high"), "score: expected number(s), got 'high'"),
        (GOOD.replace("0.0 0.0 1.0,", "0.0 0.0 1.2,"), "R: not a rotation (max |R R^T - I| = 0.44"),
        (GOOD.replace("0.0 0.0 1.0,", "0.0 0.0 -1.0,"), "R: not a rotation (max |R R^T - I| = 0, det = -1.0000"),
    ],
)
def test_bad_line_is_reported_with_its_number(tmp_path: Path, line: str, message: str) -> None:
    problems = _problems(_write(tmp_path, HEADER, GOOD, line))
    assert len(problems) == 1 and problems[0].startswith(f"line 3: {message}"), problems


def test_unknown_object_id(tmp_path: Path) -> None:
    path = _write(tmp_path, HEADER, GOOD, GOOD.replace("1,0,2,", "1,1,31,"))
    assert read_bop_results(path, known_obj_ids=range(1, 32))[1].obj_id == 31
    assert _problems(path, known_obj_ids=range(1, 31)) == [
        f"line 3: obj_id: unknown object 31 (known: {list(range(1, 31))})"
    ]


def test_inconsistent_times(tmp_path: Path) -> None:
    lines = [GOOD, GOOD.replace(",0.31", ",0.3109"), GOOD.replace(",0.31", ",0.312"), GOOD.replace("1,0,2", "1,1,2")]
    problems = _problems(_write(tmp_path, HEADER, *lines, GOOD.replace(",0.31", ",5")))
    assert [p.split(":")[0] for p in problems] == ["line 4", "line 6"]
    assert "0.312 s differs from 0.31 s of the same image (scene 1, image 0) at line 2" in problems[0]


def test_slightly_non_orthonormal_rotation_warns_once(tmp_path: Path) -> None:
    lines = [GOOD, GOOD.replace(" 0.0 1.0,", " 0.0 1.0005,"), GOOD.replace(" 0.0 1.0,", " 0.0 1.002,"),
             GOOD.replace("1,0,2,", "1,1,2,", 1)]  # fmt: skip
    with pytest.warns(ResultsWarning) as record:
        rows = read_bop_results(_write(tmp_path, HEADER, *lines))
    assert len(record) == 1
    assert "2 rotation(s) slightly non-orthonormal" in str(record[0].message) and "at line 4" in str(record[0].message)
    assert rows[2].R[2, 2] == 1.002  # used as written, never re-orthonormalised


def test_rows_repeating_an_earlier_row_warn_once(tmp_path: Path) -> None:
    """A file written twice, or two methods' rows merged: each row is scored (as by the toolkit), and said once."""
    other = GOOD.replace("1,0,2,", "1,0,3,", 1)
    with pytest.warns(ResultsWarning) as record:
        rows = read_bop_results(_write(tmp_path, HEADER, GOOD, other, GOOD.replace("0.93", "0.5"), other))
    assert len(rows) == 4 and len(record) == 1
    assert "2 row(s) repeat an earlier row's image, object and pose (first: line 4 repeats line 2)" in str(
        record[0].message
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_bop_results(_write(tmp_path, HEADER, GOOD, other, name="once_tless-test.csv"))  # no repeat: no warning


def test_all_bad_lines_reported_together(tmp_path: Path) -> None:
    lines = [HEADER, GOOD, "1,0,2", GOOD, "", GOOD.replace("0.93", "nan").replace("720.1", "-inf"), HEADER, GOOD]
    problems = _problems(_write(tmp_path, *lines, end="\n\n"))
    assert [p.split(":")[0] for p in problems][:4] == ["line 3", "line 5", "line 6", "line 6"]
    assert {p.split(":")[0] for p in problems[4:]} == {"line 7"}
    assert "got an empty line" in problems[1]
    assert "score" in problems[2] and "t:" in problems[3]
    assert problems[4].startswith("line 7: scene_id: expected a non-negative integer")  # header off line 1


def test_missing_file_and_bad_encoding(tmp_path: Path) -> None:
    with pytest.raises(ResultsError, match="not found") as info:
        read_bop_results(tmp_path / "nope_tless-test.csv")
    assert "nope_tless-test.csv" in str(info.value)
    (tmp_path / "bin.csv").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ResultsError, match="UTF-8"):
        read_bop_results(tmp_path / "bin.csv")


# --- file names ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "name, expected",
    [
        ("cendernet_tless-test.csv", ResultName("cendernet", "tless", "test")),
        ("cosypose114533-eccv2020_tless-test-primesense.csv",
         ResultName("cosypose114533-eccv2020", "tless", "test", "primesense")),
        ("m_dimo-sim_run1.csv", ResultName("m", "dimo", "sim", None, "run1")),
        ("/some/dir/m_ycbv-test-x_a_b.json.gz", ResultName("m", "ycbv", "test", "x", "a_b")),
    ],
)  # fmt: skip
def test_parse_result_filename(name: str, expected: ResultName) -> None:
    assert parse_result_filename(name) == expected


@pytest.mark.parametrize(
    "name", ["cendernet.csv", "m_tless.csv", "m_tless-test-a-b.csv", "_tless-test.csv", "m_-test.csv"]
)
def test_parse_result_filename_rejects(name: str) -> None:
    with pytest.raises(ResultsError, match="file name"):
        parse_result_filename(name)


def test_result_filename_builds_and_checks() -> None:
    assert result_filename("cendernet", "tless", "train", "pbr") == "cendernet_tless-train-pbr.csv"
    assert parse_result_filename(result_filename("cender-net", "dimo", "sim", optional_id="s0")) == ResultName(
        "cender-net", "dimo", "sim", None, "s0"
    )
    for args in [("cender_net", "tless", "test"), ("m", "t-less", "test"), ("m", "tless", "train_pbr"), ("", "a", "b"),
                 ("m.v2", "tless", "test")]:  # fmt: skip
        with pytest.raises(ConfigError):
            result_filename(*args)


# --- sidecar ------------------------------------------------------------------------------------


def test_sidecar_round_trip_and_validation(tmp_path: Path) -> None:
    csv = tmp_path / "cendernet_dimo-sim.csv"
    assert read_run_sidecar(csv) is None
    path = write_run_sidecar(csv, tmp_path / "data", "dimo", "sim", {"carrier": 2, "views": [0, 2]}, seed=7,
                             extra={"weights": "demo"})  # fmt: skip
    assert path == tmp_path / "cendernet_dimo-sim.json"
    data = read_run_sidecar(csv)
    assert data is not None
    assert data["data_root"] == str((tmp_path / "data").resolve())
    assert (data["dataset"], data["split"], data["seed"]) == ("dimo", "sim", 7)
    assert data["selection"] == {"carrier": 2, "views": [0, 2]} and data["extra"] == {"weights": "demo"}
    with pytest.raises(ConfigError, match="seed"):
        write_run_sidecar(csv, tmp_path, "dimo", "sim", {}, seed=1.5)  # type: ignore[arg-type]
    path.write_text(json.dumps({**data, "seed": "7", "selection": []}))
    with pytest.raises(ResultsError) as info:
        read_run_sidecar(csv)
    assert info.value.problems == ["selection: expected dict, got list", "seed: expected int, got str"]
    path.write_text("{not json")
    with pytest.raises(ResultsError, match="malformed JSON: .* line 1, column 2"):
        read_run_sidecar(csv)
    path.write_bytes(b'{"format": "\xff"}')
    with pytest.raises(ResultsError, match="not UTF-8"):
        read_run_sidecar(csv)
    path.write_text("[]")
    with pytest.raises(ResultsError, match="not a run sidecar"):
        read_run_sidecar(csv)


def test_sidecar_values_no_run_writes_are_refused_each_named(tmp_path: Path) -> None:
    csv = tmp_path / "cendernet_dimo-sim.csv"
    path = write_run_sidecar(csv, tmp_path / "data", "dimo", "sim", {}, seed=7)
    data = json.loads(path.read_text())
    path.write_text(json.dumps({**data, "version": -1, "seed": -3, "data_root": "", "split": " ", "results": 5}))
    with pytest.raises(ResultsError, match="malformed run sidecar") as info:
        read_run_sidecar(csv)
    assert info.value.problems == [
        "version: expected 1 to 1, got -1",
        "seed: expected a non-negative integer, got -3",
        "data_root: expected a non-empty string, got ''",
        "split: expected a non-empty string, got ' '",
        "results: expected the results file's name, got 5",
    ]


def test_sidecar_relative_data_root_is_the_sidecars_folders_and_another_results_name_is_said(tmp_path: Path) -> None:
    csv = tmp_path / "runs" / "cendernet_dimo-sim.csv"
    csv.parent.mkdir()
    path = write_run_sidecar(csv, tmp_path / "data", "dimo", "sim", {}, seed=0)
    data = json.loads(path.read_text())
    path.write_text(json.dumps({**data, "data_root": "../data"}))
    assert read_run_sidecar(csv)["data_root"] == str((tmp_path / "data").resolve())  # not the current folder's
    path.write_text(json.dumps({**data, "results": "other_dimo-sim.csv"}))
    with pytest.warns(ResultsWarning, match=r"results: the sidecar was written for other_dimo-sim.csv, not cendernet"):
        assert read_run_sidecar(csv)["dataset"] == "dimo"


@pytest.mark.parametrize(
    "header",
    ["time,t,R,score,obj_id,im_id,scene_id", "scene_id, im_id, obj_id, score, R, t, time",
     "SCENE_ID,IM_ID,OBJ_ID,SCORE,R,T,TIME", "scene_id;im_id;obj_id;score;R;t;time"],
)  # fmt: skip
def test_a_header_of_other_columns_order_case_or_separator_is_one_error(tmp_path: Path, header: str) -> None:
    """It was read as a data row, then every row failed: a flood of errors that said nothing of the header."""
    path = _write(tmp_path, header, *[GOOD] * 30)
    with pytest.raises(ResultsError) as info:
        read_bop_results(path)
    assert info.value.format() == (
        f"{path}: line 1: expected the header '{HEADER}' (or none), got {header!r}: the columns are read in that order"
    )


def test_a_long_list_of_bad_lines_is_shown_in_part(tmp_path: Path) -> None:
    path = _write(tmp_path, HEADER, *[GOOD + ",extra"] * 30)
    with pytest.raises(ResultsError) as info:
        read_bop_results(path)
    lines = info.value.format().splitlines()
    assert len(info.value.problems) == 30 and len(lines) == 1 + 20 + 1
    assert lines[-1] == "  ... and 10 more of the 30"
