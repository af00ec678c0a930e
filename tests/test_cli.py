"""The command line's doors: every number, output path and the version, checked before any work, one line each."""

from __future__ import annotations

from pathlib import Path

import pytest

from bop_cender import __version__
from bop_cender.cli import main

CSV = "scene_id,im_id,obj_id,score,R,t,time\n0,0,1,1.0,1 0 0 0 1 0 0 0 1,0 0 500,-1\n"


@pytest.fixture()
def workdir(tmp_path: Path, monkeypatch) -> Path:
    """An empty current folder with a results file and a plain file; the demo cache elsewhere (never made)."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("BOP_CENDER_CACHE", str(tmp_path / "cache"))
    (tmp_path / "gt_dimo-real.csv").write_text(CSV)
    (tmp_path / "a_file").write_text("x")
    return tmp_path


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["score", "gt_dimo-real.csv", "--vsd-delta", "-5"], "--vsd-delta: must be a finite number > 0, got '-5'"),
        (["score", "gt_dimo-real.csv", "--vsd-delta", "nan"], "--vsd-delta: must be a finite number > 0, got 'nan'"),
        (["score", "gt_dimo-real.csv", "--n-views", "0"], "--n-views: must be >= 1, got 0"),
        (["score", "gt_dimo-real.csv", "--seed", "-2"], "--seed: must be >= 0, got -2"),
        (["compare", "gt_dimo-real.csv", "--vsd-delta", "inf"], "--vsd-delta: must be a finite number > 0"),
        (["crosscheck", "gt_dimo-real.csv", "--n-views", "-1"], "--n-views: must be >= 1, got -1"),
        (["info", "--dataset", "dimo", "--n-views", "0"], "--n-views: must be >= 1, got 0"),
        (["info", "--dataset", "dimo", "--n-views", "two"], "--n-views: expected an integer, got 'two'"),
        (["run", "--dataset", "dimo", "--seed", "-1"], "--seed: must be >= 0, got -1"),
        (["run", "--dataset", "dimo", "--top-k", "0"], "--top-k: must be >= 1, got 0"),
        (["train", "--dataset", "dimo", "--out", "r", "--lr", "0"], "--lr: must be a finite number > 0, got '0'"),
        (["train", "--dataset", "dimo", "--out", "r", "--width", "-1"], "--width: must be a finite number > 0"),
        (["train", "--dataset", "dimo", "--out", "r", "--batch-size", "0"], "--batch-size: must be >= 1, got 0"),
        (["heatmaps", "--dataset", "dimo", "--limit-scenes", "-4"], "--limit-scenes: must be >= 1, got -4"),
        (["train", "--dataset", "dimo", "--out", "r", "--crop", "0x16"], "--crop: expected a positive height and"),
        (["run", "--dataset", "dimo", "--split", ""], "--split: expected a split name, got an empty one"),
        (["score", "gt_dimo-real.csv", "--split", " "], "--split: expected a split name, got an empty one"),
        (["train", "--dataset", "dimo", "--out", "r", "--val-split", ""], "--val-split: expected a split name"),
    ],
)
def test_numbers_that_make_no_sense_are_refused_as_they_are_read(workdir: Path, capsys, argv, message) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {message}") and err.count("\n") == 1, err
    assert sorted(p.name for p in workdir.iterdir()) == ["a_file", "gt_dimo-real.csv"]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["score", "gt_dimo-real.csv", "--out", "a_file"], "a_file: --out: exists and is not a directory"),
        (["score", "gt_dimo-real.csv", "--out", "a_file/out"], "a_file/out: --out: a_file is a file, not a folder"),
        (["compare", "gt_dimo-real.csv", "--out", "a_file"], "a_file: --out: exists and is not a directory"),
        (["crosscheck", "gt_dimo-real.csv", "--out", "a_file"], "a_file: --out: exists and is not a directory"),
        (["convert-pvnet", "gt_dimo-real.csv", "--out", "."], ".: --out: is a directory, expected an output file"),
        (["run", "--dataset", "dimo", "--heatmaps", "oracle", "--out", "a_file/x_dimo-real.csv"], "a_file is a file"),
        (["run", "--dataset", "dimo", "--heatmaps", "oracle", "--vis", "a_file"], "a_file: --vis: exists and is not a"),
    ],
)
def test_an_output_that_cannot_be_written_is_refused_before_any_work(workdir: Path, capsys, argv, message) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err.splitlines()  # run first says that it uses the demo (not made yet: no work)
    assert err[-1].startswith("error: ") and message in err[-1] and not any("Traceback" in e for e in err), err
    assert sorted(p.name for p in workdir.iterdir()) == ["a_file", "gt_dimo-real.csv"]


def test_version(capsys) -> None:
    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0 and capsys.readouterr().out == f"bop-cender {__version__}\n"


@pytest.mark.parametrize("command", ["score", "compare", "crosscheck"])
def test_a_directory_given_as_a_results_file_is_named_as_such(workdir: Path, capsys, command: str) -> None:
    (workdir / "x_dimo-real.csv").mkdir()
    assert main([command, "x_dimo-real.csv"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: x_dimo-real.csv: is a directory, expected a ") and err.count("\n") == 1, err


def test_crosscheck_says_a_malformed_results_file_before_looking_for_the_toolkit(workdir: Path, capsys) -> None:
    (workdir / "x_dimo-real.csv").write_text("scene_id,im_id,obj_id,score,R,t,time\n0,0,1,0.5,1 0 0,0 0 1,-1\n")
    assert main(["crosscheck", "x_dimo-real.csv", "--toolkit", str(workdir / "no_toolkit")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: x_dimo-real.csv: 1 bad line(s)") and "line 2: R: expected 9 number(s)" in err
    assert "crosscheck not run" not in err


@pytest.mark.parametrize("flag", ["--device", "--pose-device"])
def test_cuda_asked_for_without_a_cuda_device_is_one_clear_error(workdir: Path, capsys, flag: str) -> None:
    import torch

    if torch.cuda.is_available():
        pytest.skip("a CUDA device is present")
    assert main(["run", "--dataset", "dimo", "--heatmaps", "oracle", flag, "cuda"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[-1] == f"error: {flag}: CUDA was asked for but torch sees no CUDA device", err
    assert sorted(p.name for p in workdir.iterdir()) == ["a_file", "gt_dimo-real.csv"]


def test_a_cache_variable_naming_a_file_is_one_error_naming_the_variable(tmp_path, monkeypatch, capsys) -> None:
    """It read "…/demo-dimo-v2.partial: Not a directory", naming neither the variable nor what it is for."""
    (tmp_path / "afile").write_text("x")
    monkeypatch.setenv("BOP_CENDER_CACHE", str(tmp_path / "afile" / "cache"))
    assert main(["info", "--dataset", "dimo", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert (
        err == f"error: {tmp_path / 'afile'}: $BOP_CENDER_CACHE: is a file, not a folder: bop-cender's cache is"
        f" {tmp_path / 'afile' / 'cache'}\n"
    )


def test_debug_is_taken_before_or_after_the_command() -> None:
    from bop_cender.cli.app import build_parser

    parser = build_parser()
    info = ["info", "--dataset", "dimo"]
    assert parser.parse_args([*info, "--debug"]).debug and parser.parse_args(["--debug", *info]).debug
    assert parser.parse_args(info).debug is False
