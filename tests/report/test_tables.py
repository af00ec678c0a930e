"""``bop-cender compare``: CosyPose-style and converted PVNet results, a scores JSON and the paper, in one table."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np
import pytest

from bop_cender.cli import main
from bop_cender.errors import ConfigError, ResultsError, ResultsWarning
from bop_cender.eval.score_file import score_file
from bop_cender.eval.score_report import SCORE_KEYS
from bop_cender.report.tables import PAPER_TABLES, compare, reference_rows
from bop_cender.results.bop_csv import write_bop_results
from bop_cender.results.convert_pvnet import convert_pvnet
from bop_cender.synth.regression_fixture import perturb
from tests.eval.scoring_data import gt_rows, row, target_instances

COSYPOSE = "cosypose114533-eccv2020_tless-test-primesense.csv"


def cosypose_style(built, path: Path) -> None:
    """CosyPose's published multi-view format: per object and image a multi-view row (score 1 + s) beside
    single-view candidates (score <= 1), several rows per object per image, time -1 everywhere."""
    rng = np.random.default_rng(7)
    rows = []
    for s, i, _g, o, T in target_instances(built):
        for _ in range(2):  # single-view candidates: worse poses, scores <= 1, listed first
            rows.append(row(s, i, o, round(float(rng.uniform(0.5, 1.0)), 4), perturb("t_29%", T, built.models[o], rng)))
        rows.append(row(s, i, o, 1.0 + round(float(rng.uniform(0, 1)), 4), perturb("t_4.5%", T, built.models[o], rng)))
    write_bop_results(path, rows, sort=False)


def pvnet_style(built, folder: Path) -> None:
    """One ``{scene}_{im}_{obj}.npy`` per target object and image, 3x4 poses with t in metres."""
    folder.mkdir()
    by_key: dict[tuple, list[np.ndarray]] = {}
    for s, i, _g, o, T in target_instances(built):
        by_key.setdefault((s, i, o), []).append(np.concatenate([T[:3, :3], T[:3, 3:] / 1000.0], axis=1))
    for (s, i, o), poses in by_key.items():
        np.save(folder / f"{s:06d}_{i:06d}_{o:06d}.npy", np.stack(poses))


def test_compare_cosypose_pvnet_scores_json_and_paper(small_fixture, results_dir, capsys) -> None:
    cosy = results_dir / COSYPOSE
    cosypose_style(small_fixture, cosy)
    pvnet_npy = results_dir / "pvnet_npy"
    pvnet_style(small_fixture, pvnet_npy)
    pvnet = results_dir / "pvnet_tless-test.csv"
    convert_pvnet(pvnet_npy, pvnet)
    ours = results_dir / "cendernet_tless-test.csv"
    write_bop_results(ours, gt_rows(small_fixture, {3: "t_5.5%"}))
    scored = score_file(ours, data_root=small_fixture.root, out_dir=results_dir / "scores", progress=False)

    out = results_dir / "tables"
    code = main(["compare", str(cosy), str(pvnet), str(scored.scores_path), "--reference", "paper",
                 "--data-root", str(small_fixture.root), "--out", str(out), "--no-progress", "--vsd-delta", "12"])  # fmt: skip
    assert code == 0
    assert json.loads((out / f"scores_{Path(COSYPOSE).stem}.json").read_text())["metadata"]["vsd_delta"] == 12.0
    printed = capsys.readouterr().out
    table = list(csv.DictReader(io.StringIO((out / "comparison_tless-test.csv").read_text())))
    methods = [r["method"] for r in table]
    assert methods[:3] == ["cosypose114533-eccv2020", "pvnet", "cendernet"]
    assert set(methods[3:]) == {
        "CosyPose (ECCV 2020) [reported]",
        "CenDerNet [reported]",
        "CosyPose (BOP leaderboard) [reported]",
    }
    by = {r["method"]: r for r in table}
    # top-n per target takes the multi-view rows (score > 1) first: 4.5 % translations, all correct
    assert float(by["cosypose114533-eccv2020"]["AR_MSSD<5%"]) == 1.0
    assert float(by["pvnet"]["AR_MSSD"]) == 1.0  # the GT poses, converted from metres
    assert float(by["cendernet"]["AR_MSSD<5%"]) < 1.0  # its wedges are 5.5 % off
    assert by["CenDerNet [reported]"]["AR"] == "0.713" and by["CenDerNet [reported]"]["AR_MSSD<5%"] == "0.544"
    assert by["CosyPose (BOP leaderboard) [reported]"]["AR_MSPD<5px"] == ""
    md = (out / "comparison_tless-test.md").read_text()
    assert md in printed and "| cosypose114533-eccv2020 | scored " in md and md.count("\n|") == 2 + len(table)
    png = (out / "comparison_tless-test.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    assert (out / f"scores_{COSYPOSE.split('.')[0]}.json").is_file()  # CSV inputs are scored and kept


def test_reference_rows_are_filtered_and_merged() -> None:
    rows = reference_rows(PAPER_TABLES, "dimo", "sim")
    assert {r.method for r in rows} == {"PVNet [reported]", "CenDerNet [reported]"}
    cender = next(r for r in rows if r.method == "CenDerNet [reported]")
    assert cender.scores["AR_MSPD<5px"] == 0.721 and cender.scores["AR"] is None
    tless = {r.method: r for r in reference_rows(PAPER_TABLES, "tless", "test")}
    cosy = tless["CosyPose (ECCV 2020) [reported]"]
    assert "Table 3" in cosy.source and "Table 4" in cosy.source  # two tables, one row
    assert all(cosy.scores[k] is not None for k in SCORE_KEYS)


def test_compare_rejects_other_inputs(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(ConfigError, match="expected a results .csv or a scores .json"):
        compare([tmp_path / "notes.txt"], out_dir=tmp_path)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ('{"AR": "x"}', "AR: expected a recall in \\[0, 1\\] or null"),
        ('{"AR_MSSD": NaN}', "AR_MSSD: expected a recall in \\[0, 1\\] or null, got nan"),
        ('{"AR": 5.0}', "AR: expected a recall"),
        ('{"AR": -0.3}', "AR: expected a recall"),
        ('{"metadata": [1]}', "metadata: expected an object"),
        ('{"metadata": {"method": 5}}', "metadata.method: expected a string"),
        ('{"AR": 0.2}', r"AR: AR is 0.2, not the mean of AR_VSD, AR_MSSD and AR_MSPD \(0.5\)"),
        ('{"AR": null}', "AR: AR is None, not the mean"),
        ('{"AR_VSD": null}', "AR: AR is 0.5 but AR_VSD, AR_MSSD or AR_MSPD is null: expected null"),
        ("{not json", "malformed JSON"),
    ],
)
def test_a_malformed_scores_json_is_one_error_naming_the_field(tmp_path: Path, content: str, message: str) -> None:
    scores = {k: 0.5 for k in ("AR", "AR_VSD", "AR_MSSD", "AR_MSPD", "AR_MSPD<5px", "AR_MSSD<5%")}
    path = tmp_path / "scores_x.json"
    if content.startswith("{not"):
        path.write_text(content)
    else:
        path.write_text(json.dumps({**scores, **json.loads(content)}))
    with pytest.raises(ResultsError, match=message):
        compare([path], out_dir=tmp_path)


def test_a_reference_table_with_two_values_of_one_figure_is_refused_and_one_without_the_split_said(
    small_fixture, results_dir, capsys
) -> None:
    good = results_dir / "gt_tless-test.csv"
    write_bop_results(good, gt_rows(small_fixture))
    reference = results_dir / "ref.csv"
    reference.write_text("dataset,split,method,source,metric,value\ntless,test,x,y,AR,0.5\ntless,test,x,z,AR,0.7\n")
    args = ["--data-root", str(small_fixture.root), "--out", str(results_dir / "t"), "--no-progress"]
    assert main(["compare", str(good), "--reference", str(reference), *args]) == 2
    assert "row 3: x on tless test has two values of AR: 0.5 (row 2) and 0.7" in capsys.readouterr().err
    reference.write_text("dataset,split,method,source,metric,value\ndimo,sim,x,y,AR,0.5\ndimo,sim,x,y,AR,0.5\n")
    with pytest.warns(ResultsWarning, match="has no row for tless test: the table holds the inputs alone"):
        assert main(["compare", str(good), "--reference", str(reference), *args]) == 0  # one value twice: one


def test_compare_refuses_inputs_of_two_datasets_before_scoring_any(small_fixture, results_dir, capsys) -> None:
    """A DIMO row under a T-LESS heading is refused, and nothing is scored or written."""
    tless = results_dir / "gt_tless-test.csv"
    write_bop_results(tless, gt_rows(small_fixture))
    dimo = results_dir / "gt_dimo-real.csv"
    write_bop_results(dimo, gt_rows(small_fixture)[:2])
    out = results_dir / "tables"
    assert main(["compare", str(tless), str(dimo), "--data-root", str(small_fixture.root), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "a table holds one dataset and split, and the inputs are for 2" in err and err.count("\n") == 1, err
    assert "gt_tless-test.csv: tless test; gt_dimo-real.csv: dimo real" in err
    assert not out.exists()


def test_compare_names_rows_of_one_method_by_their_file(small_fixture, results_dir) -> None:
    first = results_dir / "gt_tless-test.csv"
    write_bop_results(first, gt_rows(small_fixture))
    (results_dir / "b").mkdir()
    second = results_dir / "b" / "gt_tless-test.csv"
    write_bop_results(second, gt_rows(small_fixture, {3: "t_5.5%"}))
    one = score_file(first, data_root=small_fixture.root, out_dir=results_dir / "scores", progress=False).scores_path
    two = score_file(second, data_root=small_fixture.root, out_dir=results_dir / "b", progress=False).scores_path
    comparison = compare([first, one, two], data_root=small_fixture.root, out_dir=results_dir / "t", progress=False)
    names = [r.method for r in comparison.rows]
    assert names == ["gt (gt_tless-test)", f"gt ({one})", f"gt ({two})"]
    with pytest.raises(ConfigError, match="is given twice"):
        compare([first, first], data_root=small_fixture.root, out_dir=results_dir / "u", progress=False)


def test_compare_never_writes_over_an_input_or_one_output_over_another(small_fixture, results_dir, capsys) -> None:
    """Two CSVs of one name would both write scores_<name>.json (one silently lost): each goes to out/input<k>/;
    a CSV scored beside its own scores JSON given as an input would overwrite it: refused before anything is
    scored (a fuzz found both)."""
    first = results_dir / "gt_tless-test.csv"
    write_bop_results(first, gt_rows(small_fixture))
    (results_dir / "b").mkdir()
    second = results_dir / "b" / "gt_tless-test.csv"
    write_bop_results(second, gt_rows(small_fixture, {3: "t_5.5%"}))
    out = results_dir / "t"
    args = ["--data-root", str(small_fixture.root), "--no-progress"]
    assert main(["compare", str(first), str(second), *args, "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"scores of {first}: {out / 'input1' / 'scores_gt_tless-test.json'}" in printed
    assert f"scores of {second}: {out / 'input2' / 'scores_gt_tless-test.json'}" in printed
    one, two = (json.loads((out / f"input{k}" / "scores_gt_tless-test.json").read_text()) for k in (1, 2))
    assert one["AR_MSSD"] == 1.0 and two["AR_MSSD"] < 1.0  # each CSV's scores in a folder of its own
    assert not (out / "scores_gt_tless-test.json").exists()
    stale = results_dir / "scores_gt_tless-test.json"
    score_file(first, data_root=small_fixture.root, progress=False)  # beside the CSV
    before = stale.read_bytes()
    assert main(["compare", str(first), str(stale), *args, "--out", str(results_dir)]) == 2
    assert f"--out: {stale} would be written over the input {stale}" in capsys.readouterr().err
    assert stale.read_bytes() == before


def test_compare_checks_everything_before_writing_anything(small_fixture, results_dir, capsys) -> None:
    good = results_dir / "gt_tless-test.csv"
    write_bop_results(good, gt_rows(small_fixture))
    bad = results_dir / "bad_tless-test.csv"
    bad.write_text("scene_id,im_id,obj_id,score,R,t,time\n1,0,1,x\n")  # malformed: found when it is scored
    out = results_dir / "tables"
    args = ["--data-root", str(small_fixture.root), "--out", str(out), "--no-progress"]
    assert main(["compare", str(good), str(bad), *args]) == 2
    assert "bad_tless-test.csv: 1 bad line(s)" in capsys.readouterr().err and not out.exists()
    (results_dir / "ref.csv").write_text("dataset,split,method,source,metric,value\ntless,test,x,y,AR,high\n")
    assert main(["compare", str(good), "--reference", str(results_dir / "ref.csv"), *args]) == 2
    assert "bad row 2" in capsys.readouterr().err and not out.exists()
    for bad_reference in (b"dataset,split,method,source,metric,value\ntless,test,x,y,AR,nan\n",  # not a recall
                          b"dataset,split,method,source,metric,value\ntless,test,x,y,AR,7\n",
                          b"dataset,split,method,source,metric,value\ntless,test,x,y,AR,0.5,extra\n",
                          b"dataset,split,method,source,metric,value\ntless,test,x\xff,y,AR,0.5\n"):  # fmt: skip
        (results_dir / "ref.csv").write_bytes(bad_reference)
        assert main(["compare", str(good), "--reference", str(results_dir / "ref.csv"), *args]) == 2
        err = capsys.readouterr().err
        assert ("bad row 2" in err or "not UTF-8" in err) and "Traceback" not in err and not out.exists()
    (results_dir / "a_file").write_text("x")
    assert main(["compare", str(good), *args[:2], "--out", str(results_dir / "a_file")]) == 2
    assert "a_file: --out: exists and is not a directory" in capsys.readouterr().err
    folder = results_dir / "folder.csv"
    folder.mkdir()
    assert main(["compare", str(folder), *args]) == 2
    assert "folder.csv: is a directory" in capsys.readouterr().err and not out.exists()


@pytest.mark.parametrize(
    "blocked", ["comparison_tless-test.png", "comparison_tless-test.md", "scores_gt_tless-test.json"]
)
def test_compare_refuses_an_output_it_cannot_write_before_scoring(
    small_fixture, results_dir, capsys, monkeypatch, blocked
):
    """A directory where an output goes was found when that file was written, after the others: half a
    comparison was left behind (and minutes of scoring spent)."""
    good = results_dir / "gt_tless-test.csv"
    write_bop_results(good, gt_rows(small_fixture))
    out = results_dir / "tables"
    (out / blocked).mkdir(parents=True)
    import bop_cender.report.tables as tables

    monkeypatch.setattr(tables, "score_file", lambda *a, **k: pytest.fail("scored before the outputs were checked"))
    assert main(["compare", str(good), "--data-root", str(small_fixture.root), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err == f"error: {out / blocked}: --out: is a directory, expected an output file\n"
    assert [p.name for p in out.iterdir()] == [blocked]


def test_a_bare_scores_json_is_for_the_dataset_and_split_its_name_says(tmp_path: Path, capsys) -> None:
    """A scores JSON without metadata fitted any table: one named for T-LESS went into a DIMO table."""
    scores = {k: 0.5 for k in ("AR", "AR_VSD", "AR_MSSD", "AR_MSPD", "AR_MSPD<5px", "AR_MSSD<5%")}
    tless = tmp_path / "scores_a_tless-test.json"
    tless.write_text(json.dumps(scores))
    dimo = tmp_path / "scores_b_dimo-real.json"
    dimo.write_text(json.dumps({**scores, "metadata": {"dataset": "dimo", "split": "real"}}))
    with pytest.raises(ConfigError, match="scores_a_tless-test.json: tless test; scores_b_dimo-real.json: dimo real"):
        compare([tless, dimo], out_dir=tmp_path / "t", progress=False)
    assert not (tmp_path / "t").exists()
    alone = compare([tless], out_dir=tmp_path / "u", progress=False)
    assert (alone.dataset, alone.split) == ("tless", "test") and alone.files["csv"].name == "comparison_tless-test.csv"
    other = tmp_path / "scores_c_tless-test-kinect.json"
    other.write_text(json.dumps(scores))
    assert compare([other], out_dir=tmp_path / "v", progress=False).split == "test_kinect"
    unnamed = tmp_path / "scores.json"  # no BOP name: fits any table, as before
    unnamed.write_text(json.dumps(scores))
    assert compare([unnamed, dimo], out_dir=tmp_path / "w", progress=False).dataset == "dimo"


def test_a_reference_table_needs_its_header_even_without_rows(tmp_path: Path) -> None:
    """A table "a,b" of no rows was taken, with only a warning that it had no row for the split."""
    from bop_cender.report.tables import read_reference_table

    for text, found in (("a,b\n", "header a,b"), ("# only a comment\n", "no header"), ("", "no header")):
        (tmp_path / "ref.csv").write_text(text)
        with pytest.raises(
            ConfigError, match=f"expected the header dataset,split,method,source,metric,value, found {found}"
        ):
            read_reference_table(tmp_path / "ref.csv")
    (tmp_path / "ref.csv").write_text("value,metric,source,method,split,dataset\n0.5,AR,x,m,test,tless\n")  # any order
    assert read_reference_table(tmp_path / "ref.csv")[0]["method"] == "m"
    spaced = "\ufeffdataset, split, method, source, metric, value\ntless, test, m, x, AR, 0.5\n"  # a BOM, spaces
    (tmp_path / "ref.csv").write_text(spaced, encoding="utf-8")
    assert read_reference_table(tmp_path / "ref.csv")[0] == {
        "dataset": "tless", "split": "test", "method": "m", "source": "x", "metric": "AR", "value": "0.5"
    }  # fmt: skip


def test_compare_refuses_results_that_match_no_target(small_fixture, results_dir, capsys) -> None:
    """compare scores through score: a file of another data set's images is an error, not a 0.000 row."""
    targets = set(small_fixture.target_images)
    ignored = [
        row(s, i, o, 1.0, T) for (s, i), gts in small_fixture.gt.items() if (s, i) not in targets for _, o, T in gts
    ]
    csv_path = results_dir / "gt_tless-test.csv"
    write_bop_results(csv_path, ignored)
    out = results_dir / "tables"
    assert main(["compare", str(csv_path), "--data-root", str(small_fixture.root), "--out", str(out)]) == 2
    assert f"0 of {len(ignored)} rows match a target" in capsys.readouterr().err and not out.exists()


def test_a_method_name_with_a_line_break_or_a_pipe_keeps_the_markdown_table_whole() -> None:
    from bop_cender.report.tables import Comparison, MethodRow

    scores = dict.fromkeys(SCORE_KEYS, 0.5)
    table = Comparison([MethodRow("a|b\n# hi", "scores x.json", scores, "tless", "test")], "tless", "test").markdown()
    assert table.splitlines()[-1].startswith("| a/b # hi | scores x.json | 0.500")


def test_compare_bop24_gives_map_columns_one_protocol_per_table(small_fixture, results_dir, capsys) -> None:
    """``--protocol bop24``: the CSVs scored for 6D detection, mAP columns, the protocol in the title and the files;
    a BOP'24 scores JSON joins such a table; a BOP'19 one beside it is refused; the paper has no mAP to add."""
    cosy = results_dir / COSYPOSE
    cosypose_style(small_fixture, cosy)
    ours = results_dir / "cendernet_tless-test.csv"
    write_bop_results(ours, gt_rows(small_fixture))
    out = results_dir / "tables"
    with pytest.warns(ResultsWarning, match="no mAP"):
        code = main(["compare", str(cosy), str(ours), "--protocol", "bop24", "--reference", "paper",
                     "--data-root", str(small_fixture.root), "--out", str(out), "--no-progress"])  # fmt: skip
    assert code == 0
    md = (out / "comparison_tless-test_bop24.md").read_text()
    assert "BOP'24/'25 detection scores (mAP), tless test" in md and "bop25_mAP_mm" in md and "AR_VSD" not in md
    assert "[reported]" not in md
    table = list(csv.DictReader(io.StringIO((out / "comparison_tless-test_bop24.csv").read_text())))
    assert {r["protocol"] for r in table} == {"bop24"} and float(table[1]["bop24_mAP"]) == 1.0
    assert (out / "scores_cendernet_tless-test_bop24.json").is_file()
    bop24_json = out / "scores_cendernet_tless-test_bop24.json"
    again = compare([bop24_json], out_dir=results_dir / "again", progress=False)
    assert again.protocol == "bop24" and again.rows[0].scores["bop24_mAP"] == 1.0
    bop19 = score_file(ours, data_root=small_fixture.root, out_dir=results_dir / "s19", progress=False).scores_path
    with pytest.raises(ConfigError, match="one protocol"):
        compare([bop24_json, bop19], out_dir=results_dir / "mixed", progress=False)
    assert not (results_dir / "mixed").exists() or not list((results_dir / "mixed").iterdir())
