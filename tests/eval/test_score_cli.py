"""``bop-cender score``: dataset from the file name or the run sidecar, the scores JSON and the errors CSV."""

from __future__ import annotations

import csv
import json
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from bop_cender.cli import main
from bop_cender.errors import ConfigError, ResultsError, ResultsWarning
from bop_cender.eval.score_file import choose_data, score_file
from bop_cender.eval.score_report import SCORE_KEYS
from bop_cender.results.bop_csv import write_bop_results
from bop_cender.results.files import write_run_sidecar
from tests.eval.scoring_data import gt_rows, row, target_instances


def test_score_infers_dataset_and_split_from_the_file_name(small_fixture, results_dir, capsys) -> None:
    rows = gt_rows(small_fixture)
    csv_path = results_dir / "cendernet_tless-test.csv"
    write_bop_results(csv_path, rows)
    out = results_dir / "out"
    assert (
        main(["score", str(csv_path), "--data-root", str(small_fixture.root), "--out", str(out), "--no-progress"]) == 0
    )
    printed = capsys.readouterr().out
    assert "cendernet" in printed and "AR_MSSD<5%" in printed

    data = json.loads((out / "scores_cendernet_tless-test.json").read_text())
    assert list(data)[:6] == list(SCORE_KEYS)
    assert set(data) == {*SCORE_KEYS, "recalls", "metadata"}
    assert all(data[k] == 1.0 for k in SCORE_KEYS)
    meta = data["metadata"]
    assert (meta["dataset"], meta["split"], meta["method"]) == ("tless", "test", "cendernet")
    assert meta["mspd_width"] == 720 and meta["vsd_delta"] == 15.0 and meta["targets_source"] == "file"
    assert meta["counts"]["evaluated"] == len(rows)
    assert len(data["recalls"]["vsd"]["recall"]) == 10 and len(data["recalls"]["mssd"]["recall"]) == 10

    with (out / "errors_cendernet_tless-test.csv").open() as f:
        table = list(csv.DictReader(f))
    assert len(table) == len(rows)
    assert {"scene_id", "im_id", "obj_id", "est_id", "score", "gt_id", "mssd", "mspd", "vsd_0.05", "vsd_0.50"} <= set(
        table[0]
    )
    assert all(int(r["gt_id"]) >= 0 and float(r["mssd_mm"]) < 1e-9 and r["mssd_hits"] == "10" for r in table)


def test_score_reads_the_data_root_from_the_run_sidecar(small_fixture, results_dir, capsys) -> None:
    csv_path = results_dir / "cendernet_tless-test.csv"
    write_bop_results(csv_path, gt_rows(small_fixture))
    write_run_sidecar(csv_path, small_fixture.root, "tless", "test", {"n_views": 3}, seed=4)
    choice = choose_data(csv_path)
    request = choice.request
    assert request.root == small_fixture.root.resolve() and (request.n_views, request.seed) == (3, 4)
    assert "sidecar" in choice.origin
    assert main(["score", str(csv_path), "--no-progress"]) == 0
    assert "run sidecar" in capsys.readouterr().out
    assert (results_dir / "scores_cendernet_tless-test.json").is_file()


def test_score_reads_the_models_folder_type_from_the_run_sidecar(small_fixture, results_dir) -> None:
    """`run --dataset bop --model-type cad` then `score F.csv` with no flag failed: models/ not found."""
    csv_path = results_dir / "cendernet_tless-test.csv"
    write_bop_results(csv_path, gt_rows(small_fixture))
    write_run_sidecar(csv_path, small_fixture.root, "tless", "test", {}, seed=0, extra={"model_type": "cad"})
    assert choose_data(csv_path).request.model_type == "cad"
    assert choose_data(csv_path, model_type="eval").request.model_type == "eval"  # an option given now wins
    write_run_sidecar(csv_path, small_fixture.root, "tless", "test", {}, seed=0, extra={"model_type": 3})
    with pytest.raises(ResultsError, match="extra.model_type: expected a models folder type or null, got 3"):
        choose_data(csv_path)


def test_score_refuses_a_sidecar_for_another_dataset(small_fixture, results_dir, capsys) -> None:
    csv_path = results_dir / "cendernet_tless-test.csv"
    write_bop_results(csv_path, gt_rows(small_fixture)[:1])
    write_run_sidecar(csv_path, small_fixture.root, "dimo", "real", {}, seed=0)
    message = (
        "file name says dataset 'tless', the results are of 'dimo' \\(its run sidecar cendernet_tless-test.json\\)"
    )
    with pytest.raises(ConfigError, match=message):
        choose_data(csv_path)
    assert main(["score", str(csv_path)]) == 2
    assert "the results are of 'dimo'" in capsys.readouterr().err


def test_score_refuses_a_sidecar_for_another_split_unless_told(small_fixture, results_dir) -> None:
    """A results file renamed to another split after its run: which split the rows are of is not known."""
    csv_path = results_dir / "cendernet_tless-test.csv"
    write_bop_results(csv_path, gt_rows(small_fixture)[:1])
    write_run_sidecar(csv_path, small_fixture.root, "tless", "train_pbr", {}, seed=0)
    with pytest.raises(ConfigError, match="file name says split 'test', the results are of 'train_pbr'"):
        choose_data(csv_path)
    assert choose_data(csv_path, split="test").request.split == "test"  # the user chooses
    pbr = results_dir / "cendernet_tless-train-pbr.csv"  # BOP's name of the train_pbr folder agrees
    write_bop_results(pbr, gt_rows(small_fixture)[:1])
    write_run_sidecar(pbr, small_fixture.root, "tless", "train_pbr", {}, seed=0)
    assert choose_data(pbr).request.split == "train_pbr"


def test_score_refuses_results_made_on_other_data(small_fixture, dimo_copy, results_dir, capsys) -> None:
    """T-LESS scene 2 results scored against the DIMO copy (scene 0 only): every line is named."""
    rows = [r for r in gt_rows(small_fixture) if r.scene_id == 2][:2]
    csv_path = results_dir / "cendernet_dimo-real.csv"
    write_bop_results(csv_path, rows, sort=False)
    assert main(["score", str(csv_path), "--data-root", str(dimo_copy), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "2 row(s) name data that is not in dimo real" in err
    assert "line 2: scene_id: no scene 2" in err and "line 3: scene_id: no scene 2" in err


def test_score_dimo_writes_null_for_vsd_and_ar(small_fixture, dimo_copy, results_dir) -> None:
    rows = [row(0, r.im_id, r.obj_id, r.score, r.T_cam_model, -1) for r in gt_rows(small_fixture) if r.scene_id == 1]
    csv_path = results_dir / "cendernet_dimo-real.csv"
    write_bop_results(csv_path, rows)
    assert main(["score", str(csv_path), "--data-root", str(dimo_copy), "--no-progress"]) == 0
    data = json.loads((results_dir / "scores_cendernet_dimo-real.json").read_text())
    assert data["AR"] is None and data["AR_VSD"] is None and data["recalls"]["vsd"] is None
    assert data["AR_MSSD"] is not None and data["metadata"]["targets_source"] == "rendered"


def test_other_bop_datasets_need_a_data_root(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="needs --data-root"):
        choose_data(tmp_path / "method_lmo-test.csv")
    with pytest.raises(ConfigError, match="cannot tell the dataset"):
        choose_data(tmp_path / "results.csv")
    choice = choose_data(tmp_path / "method_lmo-test.csv", data_root=tmp_path)
    assert (choice.request.loader, choice.request.dataset, choice.request.split) == ("bop", "lmo", "test")
    assert choose_data(tmp_path / "cosypose1-eccv2020_tless-test-primesense.csv").request.split_type == "primesense"


def test_file_system_errors_and_missing_results_are_one_line(small_fixture, results_dir, capsys) -> None:
    missing = results_dir / "nope_tless-test.csv"
    assert main(["score", str(missing), "--no-progress"]) == 2  # refused before any data is opened or generated
    assert "results file not found" in capsys.readouterr().err
    csv_path = results_dir / "cendernet_tless-test.csv"
    write_bop_results(csv_path, gt_rows(small_fixture)[:2])
    (results_dir / "a_file").write_text("x")
    code = main(["score", str(csv_path), "--data-root", str(small_fixture.root), "--out",
                 str(results_dir / "a_file" / "out"), "--no-progress"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: ") and "Traceback" not in err and len(err.strip().splitlines()) == 1


def non_target_rows(built) -> list:
    """One row per GT instance of the images that are on disk but not targets (the split does not select them)."""
    targets = set(built.target_images)
    return [
        row(s, i, o, 1.0, T, -1) for (s, i), gts in sorted(built.gt.items()) if (s, i) not in targets for _, o, T in gts
    ]


def test_score_without_a_data_root_does_not_use_the_demo(results_dir, tmp_path, capsys, monkeypatch) -> None:
    """No --data-root and no sidecar: refused (the demo would ignore every row and score 0), nothing generated."""
    cache = tmp_path / "cache"
    monkeypatch.setenv("BOP_CENDER_CACHE", str(cache))
    csv_path = results_dir / "gt_dimo-real.csv"
    csv_path.write_text("scene_id,im_id,obj_id,score,R,t,time\n0,0,1,1.0,1 0 0 0 1 0 0 0 1,0 0 500,-1\n")
    assert main(["score", str(csv_path), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --data-root: no data root") and "--demo" in err and err.count("\n") == 1
    assert not cache.exists() and sorted(p.name for p in results_dir.iterdir()) == [csv_path.name]


def test_score_uses_the_demo_when_asked(small_fixture, results_dir, capsys, monkeypatch) -> None:
    """--demo, or a sidecar naming the demo's root (a run on the demo), is asking for it."""
    import bop_cender.synth.demo as demo

    generated = []
    monkeypatch.setattr(demo, "demo_root", lambda layout: small_fixture.root)
    monkeypatch.setattr(demo, "ensure_demo", lambda layout, **kw: generated.append(layout) or small_fixture.root)
    csv_path = results_dir / "gt_tless-test.csv"
    write_bop_results(csv_path, gt_rows(small_fixture))
    assert main(["score", str(csv_path), "--demo", "--no-progress"]) == 0
    assert "embedded synthetic tless demo" in capsys.readouterr().err and generated == ["tless"]
    assert main(["score", str(csv_path), "--demo", "--data-root", str(small_fixture.root)]) == 2
    assert "give --data-root DIR or --demo, not both" in capsys.readouterr().err
    write_run_sidecar(csv_path, small_fixture.root, "tless", "test", {}, seed=0)
    assert main(["score", str(csv_path), "--no-progress"]) == 0  # the sidecar names the demo: made there if missing
    assert generated == ["tless", "tless"]


def test_score_refuses_a_file_that_matches_no_target(small_fixture, results_dir, capsys) -> None:
    """Every row names an image on disk that the split does not select: an error, not AR 0 with exit 0."""
    rows = non_target_rows(small_fixture)
    csv_path = results_dir / "gt_tless-test.csv"
    write_bop_results(csv_path, rows)
    out = results_dir / "out"
    code = main(["score", str(csv_path), "--data-root", str(small_fixture.root), "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert f"0 of {len(rows)} rows match a target of dataset tless test" in err
    assert f"{len(rows)} for images the split does not select" in err and "wrong --data-root" in err
    assert not out.exists()


def test_score_warns_when_only_a_fraction_matches(small_fixture, results_dir) -> None:
    matching = gt_rows(small_fixture)[:1]
    ignored = non_target_rows(small_fixture)
    csv_path = results_dir / "gt_tless-test.csv"
    write_bop_results(csv_path, matching + ignored)
    total = len(matching) + len(ignored)
    with pytest.warns(ResultsWarning, match=f"only 1 of {total} rows .* match a target of dataset tless test"):
        scored = score_file(csv_path, data_root=small_fixture.root, progress=False)
    assert any(f"only 1 of {total} rows" in n for n in json.loads(scored.scores_path.read_text())["metadata"]["notes"])


@pytest.mark.parametrize("content", ["", "\n\n  \n", "scene_id,im_id,obj_id,score,R,t,time\n"])
def test_score_refuses_a_results_file_without_estimates(small_fixture, results_dir, capsys, content) -> None:
    csv_path = results_dir / "gt_tless-test.csv"
    csv_path.write_text(content)
    code = main(["score", str(csv_path), "--data-root", str(small_fixture.root), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "no estimates (the file is empty or holds only the header)" in err and err.count("\n") == 1
    assert sorted(p.name for p in results_dir.iterdir()) == [csv_path.name]


def test_a_directory_given_as_the_results_file_is_named_as_such(results_dir, capsys) -> None:
    folder = results_dir / "gt_tless-test.csv"
    folder.mkdir()
    assert main(["score", str(folder), "--no-progress"]) == 2
    assert capsys.readouterr().err == f"error: {folder}: is a directory, expected a results file\n"


def test_score_writes_its_two_files_as_a_unit(small_fixture, results_dir, capsys) -> None:
    """The scores JSON cannot be written: the errors CSV of an earlier scoring stays as it was, and the
    error names the JSON, not a temporary file."""
    csv_path = results_dir / "gt_tless-test.csv"
    write_bop_results(csv_path, gt_rows(small_fixture))
    errors = results_dir / "errors_gt_tless-test.csv"
    errors.write_text("earlier\n")
    (results_dir / "scores_gt_tless-test.json").mkdir()
    assert main(["score", str(csv_path), "--data-root", str(small_fixture.root), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {results_dir / 'scores_gt_tless-test.json'}: ") and err.count("\n") == 1, err
    assert errors.read_text() == "earlier\n"
    assert sorted(p.name for p in results_dir.iterdir()) == sorted(
        [csv_path.name, errors.name, "scores_gt_tless-test.json"]
    )


def test_a_file_given_as_the_data_root_is_named_as_such(small_fixture, results_dir, capsys) -> None:
    csv_path = results_dir / "gt_tless-test.csv"
    write_bop_results(csv_path, gt_rows(small_fixture))
    assert main(["score", str(csv_path), "--data-root", str(csv_path), "--no-progress"]) == 2
    assert capsys.readouterr().err == f"error: {csv_path}: --data-root: is a file, expected the dataset root folder\n"


def _no_faces(text: str) -> str:
    head, body = text.split("end_header\n")
    n = int(next(h for h in head.splitlines() if h.startswith("element vertex")).split()[-1])
    head = "\n".join("element face 0" if h.startswith("element face") else h for h in head.splitlines()) + "\n"
    return head + "end_header\n" + "".join(body.splitlines(keepends=True)[:n])


def _nan_vertex(text: str) -> str:
    head, body = text.split("end_header\n")
    lines = body.splitlines(keepends=True)
    lines[0] = "nan " + lines[0].split(" ", 1)[1]
    return head + "end_header\n" + "".join(lines)


def _index_out_of_range(text: str) -> str:
    lines = text.splitlines(keepends=True)
    lines[-1] = "3 0 1 99999\n"
    return "".join(lines)


@pytest.mark.parametrize(
    ("broken", "message"),
    [
        (_no_faces, "face: expected a triangle mesh: the file has no faces"),
        (_nan_vertex, "vertex: 1 vertex coordinate(s) NaN or infinite (first: vertex 0)"),
        (_index_out_of_range, "face: 1 face(s) index vertices outside 0.."),
        (lambda text: "".join(text.splitlines(keepends=True)[:40]), "line 41: truncated: the file ends before vertex"),
        (lambda text: text[: len(text) // 2], "(the file ends there: truncated?)"),
        (lambda text: "".join(text.splitlines(keepends=True)[:-3]), "truncated: the file ends before face 93 of 96"),
        (lambda text: text[: len(text) - 4], "indices for face 95 (the file ends there: truncated?)"),
    ],
    ids=["no faces", "nan", "index out of range", "truncated", "cut in a line", "truncated faces", "cut in a face"],
)
def test_a_broken_model_is_one_error_naming_it(small_fixture, tmp_path, capsys, broken, message) -> None:
    """The scorer's own PLY reader checks what the loader's (trimesh) does: no traceback, no plausible score."""
    import shutil

    root = tmp_path / "tless"
    shutil.copytree(small_fixture.root, root)
    ply = root / "models_eval" / "obj_000001.ply"
    ply.write_text(broken(ply.read_text()))
    csv_path = tmp_path / "gt_tless-test.csv"
    write_bop_results(csv_path, gt_rows(small_fixture))
    assert main(["score", str(csv_path), "--data-root", str(root), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {ply}: ") and message in err and err.count("\n") == 1, err
    assert not (tmp_path / "scores_gt_tless-test.json").exists()


def _eight_bit(path: Path) -> None:
    import cv2

    depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(path), (depth >> 8).astype("uint8"))


def _bad_crc(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[60] ^= 0xFF  # inside the first IDAT chunk: libpng prints "libpng error: IDAT: CRC error" itself
    path.write_bytes(bytes(data))


@pytest.mark.parametrize(
    ("spoil", "message"),
    [(_eight_bit, "expected a 16-bit depth image, got 8-bit (uint8)"), (_bad_crc, "cannot decode image")],
    ids=["8-bit", "corrupt"],
)
def test_a_bad_depth_image_is_one_line_and_nothing_else(small_fixture, tmp_path, capfd, spoil, message) -> None:
    """On the file descriptor, not just sys.stderr: the decoder's own 'libpng error' line is not printed."""
    import shutil

    root = tmp_path / "tless"
    shutil.copytree(small_fixture.root, root)
    scene, im = small_fixture.target_images[0]
    depth = root / "test_primesense" / f"{scene:06d}" / "depth" / f"{im:06d}.png"
    spoil(depth)
    csv_path = tmp_path / "gt_tless-test.csv"
    write_bop_results(csv_path, gt_rows(small_fixture))
    assert main(["score", str(csv_path), "--data-root", str(root), "--no-progress"]) == 2
    assert capfd.readouterr().err == f"error: {depth}: {message}\n"


def test_score_errors_point_only_to_options_score_has(small_fixture, results_dir, capsys) -> None:
    """--dataset lm on a T-LESS folder: the message names the option to fix it with, and score has it."""
    import re

    from bop_cender.cli import build_parser

    score = build_parser()._subparsers._group_actions[0].choices["score"]
    options = {o for a in score._actions for o in a.option_strings}
    csv_path = results_dir / "gt_tless-test.csv"
    write_bop_results(csv_path, gt_rows(small_fixture))
    for extra in (["--dataset", "lm"], ["--split", "nope"], ["--model-type", "recon"]):
        assert main(["score", str(csv_path), "--data-root", str(small_fixture.root), *extra, "--no-progress"]) == 2
        err = capsys.readouterr().err
        named = set(re.findall(r"--[a-z][a-z-]+", err))
        assert named and named <= options and err.count("\n") == 1, err


def test_score_says_why_ground_truth_poses_score_below_1(small_fixture, results_dir, capsys) -> None:
    """Every GT instance's own pose, the barely visible ones first: they take two targets' top-n places."""
    rows = [
        row(s, i, o, 1.0, T)
        for (s, i) in small_fixture.target_images
        for _g, o, T in sorted(small_fixture.gt[(s, i)], key=lambda x: -x[0])
    ]
    csv_path = results_dir / "gt_tless-test.csv"
    write_bop_results(csv_path, rows, sort=False)
    assert main(["score", str(csv_path), "--data-root", str(small_fixture.root), "--no-progress"]) == 0
    out = capsys.readouterr().out
    n = len(target_instances(small_fixture))
    assert f"why not 1 (MSSD, loosest threshold): 2 of {n} target instances matched by no estimate" in out
    assert "  2 closest to an instance that is not a target (too little of it visible" in out
    assert f"  and {len(rows) - n} rows beyond the top-n cut were not evaluated" in out
    counts = json.loads((results_dir / "scores_gt_tless-test.json").read_text())["metadata"]["counts"]
    assert (counts["missed_instances"], counts["unmatched_not_visible"], counts["unmatched_duplicate"]) == (2, 2, 0)


def test_the_causes_of_unmatched_estimates_are_counted_apart(small_fixture, results_dir) -> None:
    rows = gt_rows(small_fixture)
    k1, k2 = next(
        (a, b)
        for a in range(len(rows))
        for b in range(a + 1, len(rows))
        if (rows[a].scene_id, rows[a].im_id, rows[a].obj_id) == (rows[b].scene_id, rows[b].im_id, rows[b].obj_id)
    )
    rows[k2] = row(
        rows[k2].scene_id, rows[k2].im_id, rows[k2].obj_id, 0.5, rows[k1].T_cam_model, rows[k2].time
    )  # a duplicate
    far = rows[-1].T_cam_model.copy()
    far[:3, 3] += 5000.0
    rows[-1] = row(rows[-1].scene_id, rows[-1].im_id, rows[-1].obj_id, 1.0, far, rows[-1].time)
    csv_path = results_dir / "gt_tless-test.csv"
    write_bop_results(csv_path, rows)
    with pytest.warns(ResultsWarning, match="1 row\\(s\\) repeat an earlier row's image, object and pose"):
        c = score_file(csv_path, data_root=small_fixture.root, progress=False).report.metadata.counts
    assert (c.missed_instances, c.unmatched_not_visible, c.unmatched_duplicate, c.unmatched_far) == (2, 0, 1, 1)
    assert c.beyond_top_n == 0


def test_perfect_results_need_no_explanation(small_fixture, results_dir, capsys) -> None:
    csv_path = results_dir / "gt_tless-test.csv"
    write_bop_results(csv_path, gt_rows(small_fixture))
    assert main(["score", str(csv_path), "--data-root", str(small_fixture.root), "--no-progress"]) == 0
    assert "why not 1" not in capsys.readouterr().out


def test_score_refuses_a_dataset_option_that_contradicts_the_name(small_fixture, results_dir, capsys) -> None:
    """`--dataset dimoo` (a typo) would open the folder with the generic BOP loader and print a meaningless score."""
    csv_path = results_dir / "cendernet_tless-test.csv"
    write_bop_results(csv_path, gt_rows(small_fixture)[:1])
    write_run_sidecar(csv_path, small_fixture.root, "tless", "test", {}, seed=0)
    with pytest.raises(
        ConfigError, match="--dataset: the file name and its run sidecar say dataset 'tless', not 'tlesss'"
    ):
        choose_data(csv_path, dataset="tlesss")
    assert main(["score", str(csv_path), "--dataset", "lmo", "--no-progress"]) == 2
    assert "say dataset 'tless', not 'lmo'" in capsys.readouterr().err
    assert choose_data(csv_path, dataset="tless").request.dataset == "tless"


def test_score_refuses_a_split_option_that_contradicts_the_name(small_fixture, results_dir, capsys) -> None:
    """`score cendernet_dimo-sim.csv --split real` scored sim rows against real's GT with exit 0 (a fuzz found it)."""
    csv_path = results_dir / "cendernet_tless-test.csv"
    write_bop_results(csv_path, gt_rows(small_fixture)[:1])
    write_run_sidecar(csv_path, small_fixture.root, "tless", "test", {}, seed=0)
    with pytest.raises(ConfigError, match="--split: the file name and its run sidecar say split 'test', not 'train'"):
        choose_data(csv_path, split="train")
    assert main(["score", str(csv_path), "--split", "val", "--no-progress"]) == 2
    assert "say split 'test', not 'val': results of one split are not scored on another" in capsys.readouterr().err
    assert choose_data(csv_path, split="test").request.split == "test"
    renamed = (
        results_dir / "cendernet_tless-val.csv"
    )  # renamed after the run: --split chooses, as the name's error says
    csv_path.rename(renamed)
    csv_path.with_suffix(".json").rename(renamed.with_suffix(".json"))
    with pytest.warns(ResultsWarning, match="the sidecar was written for cendernet_tless-test.csv"):
        assert choose_data(renamed, split="test").request.split == "test"
    csv_path = results_dir / "other_tless-test.csv"  # no sidecar: the name alone
    write_bop_results(csv_path, gt_rows(small_fixture)[:1])
    with pytest.raises(ConfigError, match="--split: the file name says split 'test', not 'val'"):
        choose_data(csv_path, split="val")


def test_missed_instances_alone_are_said_without_an_empty_list(small_fixture, results_dir, capsys) -> None:
    """Every estimate matches but some instances have none: one line saying so, not a colon before nothing."""
    csv_path = results_dir / "gt_tless-test.csv"
    write_bop_results(csv_path, gt_rows(small_fixture)[:-1])
    assert main(["score", str(csv_path), "--data-root", str(small_fixture.root), "--no-progress"]) == 0
    why = [line for line in capsys.readouterr().out.splitlines() if line.startswith("why not 1")]
    assert len(why) == 1 and why[0].endswith("matches an instance (the missed ones have no estimate)"), why
    assert "1 of" in why[0]


def test_translations_in_metres_are_refused_not_scored_zero(small_fixture, results_dir, capsys) -> None:
    """Every estimate "farther than the loosest threshold", AR 0.000 and exit 0 (a fuzz found it): refused."""
    csv_path = results_dir / "metres_tless-test.csv"
    rows = gt_rows(small_fixture)
    write_bop_results(csv_path, [replace(r, t=r.t / 1000.0) for r in rows])
    assert main(["score", str(csv_path), "--data-root", str(small_fixture.root), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "t: implausible translations: the objects would lie a median" in err and "were they in metres?" in err
    assert not (results_dir / "scores_metres_tless-test.json").exists()


def test_an_absurd_translation_is_a_miss_without_a_numpy_warning(small_fixture, results_dir, capsys) -> None:
    """A row's t of 1e300 mm printed "warning: overflow encountered in multiply" (no file, no line): it is a miss."""
    rows = gt_rows(small_fixture)
    csv_path = results_dir / "huge_tless-test.csv"
    write_bop_results(csv_path, [replace(rows[0], t=np.array([1e300, 0.0, 1e300])), *rows[1:]])
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        scored = score_file(csv_path, data_root=small_fixture.root, progress=False, render_process=False)
    assert 0.9 < scored.report.scores["AR_MSSD"] < 1.0


def test_placeholder_translations_are_left_out_of_the_metres_check_and_a_file_of_them_refused(
    small_fixture, results_dir, capsys
) -> None:
    rows = gt_rows(small_fixture)
    csv_path = results_dir / "zeros_tless-test.csv"
    write_bop_results(csv_path, [replace(r, t=np.zeros(3)) if k % 3 == 0 else r for k, r in enumerate(rows)])
    assert main(["score", str(csv_path), "--data-root", str(small_fixture.root), "--no-progress"]) == 0  # some t = 0
    write_bop_results(csv_path, [replace(r, t=np.zeros(3)) for r in rows])
    assert main(["score", str(csv_path), "--data-root", str(small_fixture.root), "--no-progress"]) == 2
    assert "t: every estimate" in capsys.readouterr().err
