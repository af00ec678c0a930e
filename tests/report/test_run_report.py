"""``bop-cender report`` and ``run --report``: the page's content against ``score``, its figures, its errors."""

from __future__ import annotations

import json
import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from bop_cender.cli import main
from bop_cender.errors import ConfigError, ResultsError, ResultsWarning
from bop_cender.eval.score_file import score_file
from bop_cender.report.run_report import DRAWN_HERE, FROM_RUN, default_report_dir, figure_name, write_report

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def page(report_run, tmp_path_factory) -> Path:
    """The report of the fixture run, written by the library with its defaults (vis folder from the sidecar)."""
    out = tmp_path_factory.mktemp("page") / "page"
    written = write_report(report_run, out)
    assert written.index == out / "index.html" and (written.from_run, written.drawn, written.scenes) == (1, 1, 2)
    return out


def summary(folder: Path) -> dict:
    return json.loads((folder / "report.json").read_text())


def test_the_scores_are_those_score_prints(report_run, page, capsys):
    scored = score_file(report_run, progress=False, write=False, render_process=False)
    run_row = summary(page)["scores"][0]
    assert run_row["method"] == "cendernet-oracle"
    assert {k: run_row[k] for k in scored.report.scores} == scored.report.scores
    text = (page / "index.html").read_text()
    assert main(["score", str(report_run), "--no-progress", "--out", str(page.parent / "scores")]) == 0
    printed = capsys.readouterr().out.splitlines()[1].split()  # the method's row of score's table
    assert printed[0] == "cendernet-oracle"
    for shown in printed[1:]:  # each figure as score prints it, in the page's run row
        assert f'<td class="num">{shown}</td>' in text.split('<tr class="run">')[1].split("</tr>")[0]
    assert "CenDerNet [reported]" in text and "CenDerNet paper Table 2" in text  # the paper's rows of DIMO real


def test_per_object_recall_adds_up_to_the_score(report_run, page):
    data = summary(page)
    objects = data["objects"]
    assert [o["object"] for o in objects] == ["3", "4"] and all(o["instances"] > 0 for o in objects)
    total = sum(o["instances"] for o in objects)
    for key in ("AR_MSSD", "AR_MSPD", "AR_MSSD<5%", "AR_MSPD<5px"):
        weighted = sum(o[key] * o["instances"] for o in objects) / total
        assert weighted == pytest.approx(data["scores"][0][key], abs=1e-12), key
    assert '<h2 id="objects">Per object</h2>' in (page / "index.html").read_text()


def test_plots_are_written_and_shown(page):
    for name in ("mssd", "mspd"):
        assert (page / "plots" / f"{name}.png").read_bytes()[:8] == PNG
        assert f'src="plots/{name}.png"' in (page / "index.html").read_text()


def test_scenes_come_worst_first_each_with_its_figure(report_run, page):
    scenes = summary(page)["scenes"]
    measures = [s["measure"] for s in scenes]
    assert measures == sorted(measures) and len(scenes) == 2
    sources = {s["scene"]: s["figure_source"] for s in scenes}
    assert sources == {"000000": FROM_RUN, "000001": DRAWN_HERE}  # the fixture removed the run's figure of 000001
    text = (page / "index.html").read_text()
    order = [m for m in re.findall(r'<figure id="scene-([^"]+)"', text)]
    assert order == [s["scene"] for s in scenes]
    run_figure = Path(report_run.parent.parent / "vis" / "000000.png")
    assert (page / "scenes" / "000000.png").read_bytes() == run_figure.read_bytes()
    assert (page / "scenes" / "000001.png").read_bytes()[:8] == PNG
    assert figure_name("000123/17") == "000123__17.png"


def test_timings_and_settings_of_the_sidecar_are_shown(report_run, page):
    extra = json.loads(report_run.with_suffix(".json").read_text())["extra"]
    stages = extra["timings"]["stages"]
    assert set(stages) == {"heatmaps", "centers", "poses"} and set(extra["timings"]["scenes"]) == {"000000", "000001"}
    text = (page / "index.html").read_text()
    for stage, seconds in stages.items():
        assert f'<td>{stage}</td><td class="num">{seconds:.1f}</td>' in text
    assert "&quot;candidates&quot;" in text and "Failed scenes</h2><p>None.</p>" in text


def _copy_run(report_run: Path, folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / report_run.name
    shutil.copyfile(report_run, out)
    shutil.copyfile(report_run.with_suffix(".json"), out.with_suffix(".json"))
    return out


def test_failed_scenes_are_listed_first_with_why(report_run, tmp_path):
    out = _copy_run(report_run, tmp_path)
    lines = out.read_text().splitlines()
    out.write_text("\n".join([lines[0]] + [ln for ln in lines[1:] if not ln.startswith("1,")]) + "\n")  # scene 000001
    sidecar = json.loads(out.with_suffix(".json").read_text())
    sidecar["extra"]["failed_scenes"] = {"000001": "RuntimeError: rgb/000000.png: <truncated> image"}
    out.with_suffix(".json").write_text(json.dumps(sidecar))
    with pytest.warns(ResultsWarning, match="the run failed on 1 scene"):
        written = write_report(out, vis_dir=tmp_path / "no-vis")
    data = summary(written.folder)
    assert data["failed_scenes"] == sidecar["extra"]["failed_scenes"]
    assert data["scenes"][0]["scene"] == "000001" and data["scenes"][0]["measure"] == 0.0
    text = written.index.read_text()
    assert "Failed scenes (1)" in text and "rgb/000000.png: &lt;truncated&gt; image" in text  # escaped
    assert written.drawn == 2 and written.folder == default_report_dir(out)


def test_a_detection_run_with_report_shows_map(tmp_path, capsys, report_run):
    root = report_run.parent.parent / "dimo"
    out = tmp_path / "cendernet-oracle_dimo-real.csv"
    code = main(["run", "--heatmaps", "oracle", "--dataset", "dimo", "--data-root", str(root), "--split", "real",
                 "--out", str(out), "--candidates", "32", "--top-k", "1", "--limit-scenes", "1", "--no-progress",
                 "--deterministic-time", "--task", "detection", "--report"])  # fmt: skip
    assert code == 0
    folder = tmp_path / "cendernet-oracle_dimo-real_report"
    assert f"wrote {folder / 'index.html'} (1 scenes; figures: 0 from the run, 1 drawn" in capsys.readouterr().out
    data = summary(folder)
    scored = score_file(out, progress=False, write=False, render_process=False)
    assert data["protocol"] == "bop24" and data["scores"][0]["bop24_mAP"] == scored.report.scores["bop24_mAP"]
    assert len(data["scores"]) == 1  # the paper reports no mAP
    text = (folder / "index.html").read_text()
    assert "<th>bop24_mAP</th>" in text and "The paper reports no BOP&#x27;24 figure" in text
    assert "not recorded (the run recorded none (--deterministic-time" in text
    assert [o["object"] for o in data["objects"]] and all(0 <= o["mAP_mssd"] <= 1 for o in data["objects"])


def test_run_score_and_report_score_the_file_once(tmp_path, capsys, report_run, monkeypatch):
    """``run --score --report``: the page shows the scores ``--score`` computed, not scored a second time."""
    import bop_cender.eval.score_file as score_module

    calls = []
    real = score_module.score_file
    monkeypatch.setattr(score_module, "score_file", lambda *a, **kw: calls.append(real(*a, **kw)) or calls[-1])
    root = report_run.parent.parent / "dimo"
    out = tmp_path / "cendernet-oracle_dimo-real.csv"
    code = main(["run", "--heatmaps", "oracle", "--dataset", "dimo", "--data-root", str(root), "--split", "real",
                 "--out", str(out), "--candidates", "32", "--top-k", "1", "--limit-scenes", "1", "--no-progress",
                 "--deterministic-time", "--score", "--report"])  # fmt: skip
    assert code == 0 and len(calls) == 1
    assert (tmp_path / "scores_cendernet-oracle_dimo-real.json").is_file()  # --score's files, written once
    page = summary(tmp_path / "cendernet-oracle_dimo-real_report")["scores"][0]
    assert page["AR_MSSD"] == calls[0].report.scores["AR_MSSD"]


def test_a_csv_without_sidecar_needs_the_data_options_as_score_does(report_run, tmp_path, capsys):
    out = tmp_path / report_run.name
    shutil.copyfile(report_run, out)
    assert main(["report", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "--data-root" in err and not list(tmp_path.glob("*_report"))
    root = report_run.parent.parent / "dimo"
    assert main(["report", str(out), "--data-root", str(root), "--no-progress", "--max-figures", "1"]) == 0
    text = (tmp_path / "cendernet-oracle_dimo-real_report" / "index.html").read_text()
    assert "run sidecar none" in text and "Figures of the 1 worst scenes" in text
    assert len(list((tmp_path / "cendernet-oracle_dimo-real_report" / "scenes").iterdir())) == 1


def _no_leftovers(folder: Path) -> None:
    assert not [p.name for p in folder.iterdir() if p.name.startswith(".")], "a temporary folder was left behind"


@pytest.mark.parametrize(
    "edit, message",
    [
        ("missing", "cendernet-oracle_dimo-real.csv: results file not found"),
        ("bad row", "cendernet-oracle_dimo-real.csv"),
        ("unknown object", "obj_id"),
        ("bad sidecar", "cendernet-oracle_dimo-real.json: extra.timings.stages.poses: expected seconds"),
        ("not json", "cendernet-oracle_dimo-real.json"),
    ],
)
def test_bad_input_is_one_error_naming_the_file_and_nothing_is_written(report_run, tmp_path, capsys, edit, message):
    out = _copy_run(report_run, tmp_path / "in")
    if edit == "missing":
        out.unlink()
    elif edit == "bad row":
        out.write_text(out.read_text() + "0,0,3,1.0,oops\n")
    elif edit == "unknown object":
        lines = out.read_text().splitlines()
        out.write_text("\n".join([*lines, re.sub(r"^(\d+,\d+,)\d+", r"\g<1>99", lines[1])]) + "\n")
    elif edit == "bad sidecar":
        sidecar = json.loads(out.with_suffix(".json").read_text())
        sidecar["extra"]["timings"]["stages"]["poses"] = "slow"
        out.with_suffix(".json").write_text(json.dumps(sidecar))
    else:
        out.with_suffix(".json").write_text("{not json")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ResultsWarning)
        code = main(["report", str(out), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: ") and message in err, err
    assert not (tmp_path / "in" / "cendernet-oracle_dimo-real_report").exists()
    _no_leftovers(tmp_path / "in")


def test_out_must_be_a_folder_for_a_report(report_run, tmp_path, capsys):
    a_file = tmp_path / "page.html"
    a_file.write_text("mine")
    assert main(["report", str(report_run), "--out", str(a_file), "--no-progress"]) == 2
    assert "page.html: --out: exists and is not a directory" in capsys.readouterr().err
    assert a_file.read_text() == "mine"
    busy = tmp_path / "work"
    busy.mkdir()
    (busy / "notes.txt").write_text("keep me")
    with pytest.raises(ConfigError, match="is not a bop-cender report"):
        write_report(report_run, busy)
    assert [p.name for p in busy.iterdir()] == ["notes.txt"]


def test_a_rerun_replaces_the_report_and_a_failure_keeps_the_old_one(report_run, tmp_path, monkeypatch):
    folder = tmp_path / "page"
    write_report(report_run, folder, max_figures=0)
    (folder / "stale.txt").write_text("from before")
    first = (folder / "index.html").read_text()
    import bop_cender.report.run_report as run_report

    def broken(*args, **kwargs):
        raise ResultsError("drawing failed", file="x")

    monkeypatch.setattr(run_report, "render_page", broken)
    with pytest.raises(ResultsError, match="drawing failed"):
        write_report(report_run, folder, max_figures=0)
    assert (folder / "index.html").read_text() == first and (folder / "stale.txt").is_file()  # the old one stands
    _no_leftovers(tmp_path)
    monkeypatch.undo()
    written = write_report(report_run, folder, max_figures=1)
    assert not (folder / "stale.txt").exists() and written.from_run + written.drawn == 1
    _no_leftovers(tmp_path)


def test_the_drawn_figure_colours_follow_the_scorers_verdicts(report_run, page):
    """The drawn figure of scene 000001 holds green outlines (its rows hit at 5 %: the oracle's poses)."""
    import cv2

    image = cv2.imread(str(page / "scenes" / "000001.png"))[:, :, ::-1].astype(np.int64)
    green = (np.abs(image - np.array([26, 230, 26])) < 30).all(-1)  # scene_figure.RIGHT as uint8
    assert green.sum() > 50
