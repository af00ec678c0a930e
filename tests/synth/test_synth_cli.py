"""``bop-cender synth`` and ``bop-cender info`` through the command line: a tiny dataset written, resumed, described."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bop_cender.cli import main
from bop_cender.synth.record import RECORD_FILE
from bop_cender.synth.write_dimo import DIMO_CATALOGUE_SEED
from bop_cender.synth.write_tless import TLESS_CATALOGUE_SEED


def test_synth_writes_resumes_and_info_describes(tmp_path: Path, capsys) -> None:
    out = tmp_path / "tless"
    args = ["synth", "--layout", "tless", "--out", str(out), "--scenes", "1", "--views", "2", "--pbr-scenes", "0",
            "--no-contact-sheets"]  # fmt: skip
    assert main(args) == 0
    assert "1 scene folders written, 0 already complete" in capsys.readouterr().err  # summary beside the bar
    assert main(args) == 0  # resumed: nothing to do
    assert "0 scene folders written, 1 already complete" in capsys.readouterr().err
    assert (out / RECORD_FILE).is_file()  # the root record: the loaders behind info do not trip on it
    assert main(["info", "--dataset", "tless", "--data-root", str(out), "--split", "test"]) == 0
    assert "tless" in capsys.readouterr().out


def test_synth_into_a_path_that_cannot_be_a_folder_is_one_error(tmp_path: Path, capsys) -> None:
    (tmp_path / "a_file").write_text("x")
    code = main(["synth", "--layout", "tless", "--out", str(tmp_path / "a_file" / "ds"), "--scenes", "1"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: ") and "Traceback" not in err and len(err.strip().splitlines()) == 1


def models_only(layout: str, out: Path, *extra: str) -> list[str]:
    return ["synth", "--layout", layout, "--out", str(out), "--models-only", *extra]


@pytest.mark.parametrize("layout, default", [("tless", TLESS_CATALOGUE_SEED), ("dimo", DIMO_CATALOGUE_SEED)])
def test_catalogue_seed_flag(tmp_path: Path, capsys, layout: str, default: int) -> None:
    models = "models_cad" if layout == "tless" else "models"
    assert main(models_only(layout, tmp_path / "default", "--seed", "9")) == 0
    assert main(models_only(layout, tmp_path / "other", "--catalogue-seed", "5")) == 0
    records = [json.loads((tmp_path / d / RECORD_FILE).read_text()) for d in ("default", "other")]
    assert [(r["seed"], r["catalogue_seed"]) for r in records] == [(9, default), (0, 5)]
    info = [(tmp_path / d / models / "models_info.json").read_text() for d in ("default", "other")]
    assert info[0] != info[1]


def test_a_resume_with_another_seed_is_one_error_naming_the_record(tmp_path: Path, capsys) -> None:
    out = tmp_path / "ds"
    assert main(models_only("tless", out)) == 0
    capsys.readouterr()
    for flag, field in (("--seed", "seed"), ("--catalogue-seed", "catalogue_seed")):
        assert main(models_only("tless", out, flag, "1")) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
        assert f"{out / RECORD_FILE}: {field}: this dataset was generated with {field}" in err


@pytest.mark.parametrize("flag", ["--seed", "--catalogue-seed"])
def test_negative_seeds_are_refused(tmp_path: Path, capsys, flag: str) -> None:
    assert main(models_only("tless", tmp_path / "ds", flag, "-1")) == 2
    err = capsys.readouterr().err
    assert f"{flag}: must be >= 0" in err and not (tmp_path / "ds").exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--layout", "dimo", "--scenes", "0"], "--scenes: a dataset with no scene: give --scenes N (N >= 1), or"),
        (["--layout", "tless", "--scenes", "0", "--pbr-scenes", "0"], "give --scenes N or --pbr-scenes N (N >= 1)"),
        (["--layout", "tless"], "--scenes: required: the number of scenes (--models-only for the models alone)"),
        (["--layout", "tless", "--models-only", "--scenes", "2"], "--models-only writes no scene"),
        (["--layout", "tless", "--scenes", "1", "--views", "0"], "--views: must be >= 1, got 0"),
        (["--layout", "tless", "--scenes", "1", "--workers", "0"], "--workers: must be >= 1, got 0"),
        (["--layout", "tless", "--scenes", "1", "--pbr-images", "-3"], "--pbr-images: must be >= 1, got -3"),
        (["--layout", "tless", "--scenes", "x"], "--scenes: expected an integer, got 'x'"),
        (["--layout", "tless", "--models-only", "--pbr-scenes", "2"], "--pbr-scenes: --models-only writes no scene"),
        (["--layout", "dimo", "--scenes", "1", "--pbr-scenes", "2"], "--pbr-scenes: is a tless option; --layout dimo"),
        (["--layout", "dimo", "--scenes", "1", "--pbr-images", "2"], "--pbr-images: is a tless option; --layout dimo"),
        (["--layout", "tless", "--scenes", "1", "--variants", "0"], "--variants: is a dimo option; --layout tless"),
        (["--layout", "tless", "--scenes", "1", "--carriers", "1"], "--carriers: is a dimo option; --layout tless"),
        (["--layout", "tless", "--scenes", "1", "--compositions", "1"], "--compositions: is a dimo option"),
        (["--layout", "dimo", "--scenes", "1", "--variants", "0,0"], "--variants: 0 given twice in '0,0': each value"),
        (["--layout", "dimo", "--scenes", "1", "--carriers", "2,1,2"], "--carriers: 2 given twice in '2,1,2'"),
    ],
)
def test_numbers_that_make_no_dataset_are_refused(tmp_path: Path, capsys, argv: list[str], message: str) -> None:
    assert main(["synth", "--out", str(tmp_path / "ds"), *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1, err
    assert not (tmp_path / "ds").exists()


def test_synth_refuses_a_folder_it_did_not_make_unless_forced(tmp_path: Path, capsys) -> None:
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    assert main(models_only("tless", out)) == 2
    err = capsys.readouterr().err
    assert f"{out}: --out: not empty (notes.txt) and not a dataset bop-cender synth made" in err and "--force" in err
    assert [p.name for p in out.iterdir()] == ["notes.txt"]
    assert main(models_only("tless", out, "--force")) == 0
    assert main(models_only("tless", out)) == 0  # now it has the record: a resume
    (tmp_path / "a_file").write_text("x")
    assert main(models_only("tless", tmp_path / "a_file")) == 2
    assert "a_file: --out: exists and is not a directory" in capsys.readouterr().err


def test_appearance_flag(tmp_path: Path, capsys) -> None:
    out = tmp_path / "dimo"
    assert main(models_only("dimo", out, "--appearance", "randomised")) == 0
    assert json.loads((out / RECORD_FILE).read_text())["appearance"] == "randomised"
    capsys.readouterr()
    assert main(models_only("dimo", out)) == 2  # a resume with DIMO's look would mix two looks
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "field appearance" not in err
    assert f"{out / RECORD_FILE}: appearance: this dataset was generated with appearance 'randomised'" in err
    assert "--appearance randomised" in err
    tless = tmp_path / "tless"
    assert main(models_only("tless", tless, "--appearance", "randomised")) == 0
    assert json.loads((tless / RECORD_FILE).read_text())["appearance"] == "randomised"
    with pytest.raises(SystemExit):  # argparse's one-line error; "dimo" was the default's name before T-LESS had one
        main(models_only("dimo", tmp_path / "x", "--appearance", "dimo"))
    assert "--appearance: invalid choice: 'dimo'" in capsys.readouterr().err


def test_appearance_choices_are_the_styles_appearances() -> None:
    """The CLI lists them literally (importing the styles loads torch); they must not drift apart."""
    from bop_cender.cli.app import build_parser
    from bop_cender.synth.styles import APPEARANCES

    synth = build_parser()._subparsers._group_actions[0].choices["synth"]
    action = next(a for a in synth._actions if a.dest == "appearance")
    assert tuple(action.choices) == APPEARANCES and action.default == APPEARANCES[0]


def tiny(layout: str, out: Path, *extra: str) -> list[str]:
    return ["synth", "--layout", layout, "--out", str(out), "--scenes", "1", "--no-contact-sheets", *extra]


@pytest.mark.parametrize(
    ("layout", "first", "resumed", "file", "field"),
    [
        ("tless", ["--views", "2", "--pbr-scenes", "0"], ["--views", "3", "--pbr-scenes", "0"], "scene_camera", "--views"),
        ("dimo", ["--views", "2", "--variants", "0"], ["--views", "3", "--variants", "0"], "scene_camera", "--views"),
        ("dimo", ["--views", "1", "--variants", "0"], ["--views", "1", "--variants", "0", "--carriers", "1"],
         "scene_info", "--carriers"),
        ("dimo", ["--views", "1", "--variants", "0"], ["--views", "1", "--variants", "0", "--compositions", "0"],
         "scene_info", "--compositions"),
    ],
)  # fmt: skip
def test_a_resume_that_would_write_the_done_folders_otherwise_is_refused(
    tmp_path: Path, capsys, layout, first, resumed, file, field
) -> None:
    """The done folders' own files are the check (no record field): another view count, carrier or
    composition would mix two datasets, and nothing is written."""
    out = tmp_path / "ds"
    assert main(tiny(layout, out, *first)) == 0
    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    record = (out / "bop_cender_synth.json").read_bytes()
    capsys.readouterr()
    assert main(tiny(layout, out, *resumed)) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert f"{file}.json: {field}: this done scene folder has" in err and "resuming would mix two datasets" in err
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == before
    assert (out / "bop_cender_synth.json").read_bytes() == record  # still complete: nothing was written
    assert main(tiny(layout, out, *first)) == 0  # the options it was made with resume it


def test_dimo_views_other_than_13_say_what_the_readers_use(tmp_path: Path, capsys) -> None:
    assert main(tiny("dimo", tmp_path / "ds", "--views", "5", "--variants", "0")) == 0
    err = capsys.readouterr().err
    assert "--views 5: run, train and heatmaps read the paper's viewpoints 0, 2, 4, 6, 8, 10, 12" in err
    assert "they will use 3 of the 5 written per folder" in err
