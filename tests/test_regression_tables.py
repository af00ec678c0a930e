"""The regression check of scripts/regression.py as a test: every number equals the committed tables and the
official toolkit's anchor (results/regression/README.md)."""

from __future__ import annotations

from pathlib import Path

import pytest

from bop_cender.regression import compare_tables, format_problems, run_regression

TABLES_DIR = Path(__file__).resolve().parents[1] / "results" / "regression"


@pytest.fixture(scope="module")
def run():
    """One seeded regression evaluation, shared by both tests (it takes a few seconds)."""
    return run_regression()


def test_scores_equal_the_committed_tables_and_the_toolkit_anchor(run) -> None:
    problems = compare_tables(run, TABLES_DIR)
    assert not problems, format_problems(problems)
    assert run.report.metadata.counts.evaluated > 20 and run.report.vsd_recalls is not None
    assert run.detection.counts.cut > 0 and run.detection.counts.evaluated > 100  # the BOP'24 part is not vacuous


def test_a_drift_is_reported_as_a_diff(run, tmp_path) -> None:
    """The check is not vacuous: change one recall in a copy of the tables and it is named."""
    from bop_cender.regression import ANCHOR, ANCHOR_BOP24, OURS

    for name in (*OURS, *ANCHOR, ANCHOR_BOP24):
        (tmp_path / name).write_text((TABLES_DIR / name).read_text())
    lines = (tmp_path / "scores.csv").read_text().splitlines()
    metric, tau, th, value = lines[1].split(",")
    lines[1] = ",".join([metric, tau, th, f"{float(value) + 0.01:.9f}"])
    (tmp_path / "scores.csv").write_text("\n".join(lines) + "\n")
    problems = compare_tables(run, tmp_path)
    assert problems == [f"scores.csv: {metric}//{th}: value: expected {float(value) + 0.01:.9f}, got {value}"]
    (tmp_path / "scores.csv").write_text((TABLES_DIR / "scores.csv").read_text())
    lines = (tmp_path / ANCHOR_BOP24).read_text().splitlines()  # the BOP'24 anchor: one AP of the toolkit changed
    metric, obj, th, value = lines[1].split(",")
    lines[1] = ",".join([metric, obj, th, f"{float(value) + 0.01:.9f}"])
    (tmp_path / ANCHOR_BOP24).write_text("\n".join(lines) + "\n")
    assert compare_tables(run, tmp_path) == [
        f"toolkit anchor BOP'24 scores: {metric}/{obj}/{th}: value: expected {float(value) + 0.01:.9f}, got {value}"
    ]


def test_the_scripts_folders_are_checked_before_the_fixture_is_scored(tmp_path, capsys) -> None:
    """--tables of a typo read as four missing tables ("drift", exit 1); --anchor of a folder that is not the toolkit
    ended in a traceback."""
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "scripts" / "regression.py"
    spec = importlib.util.spec_from_file_location("regression_script", path)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    assert script.main(["--tables", str(tmp_path / "nowhere")]) == 2
    assert capsys.readouterr().err == f"error: {tmp_path / 'nowhere'}: --tables: tables folder not found\n"
    assert script.main(["--anchor", str(tmp_path / "no_toolkit")]) == 2
    assert "--anchor: the official toolkit's folder not found" in capsys.readouterr().err
    (tmp_path / "not_a_toolkit").mkdir()  # refused before the fixture is scored, not a traceback after it
    assert script.main(["--anchor", str(tmp_path / "not_a_toolkit"), "--tables", str(tmp_path / "new")]) == 2
    assert "--anchor: the BOP toolkit (bop_toolkit_lib) is not importable" in capsys.readouterr().err
