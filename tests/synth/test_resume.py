"""A resumed ``synth`` skips only what is really done, before any set-up, and ends byte-identical to a fresh run."""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

import pytest

from bop_cender.cli import main
from bop_cender.synth import generate as generate_module
from bop_cender.synth import layouts, write_dimo
from bop_cender.synth.done import marker_path, scene_done
from bop_cender.synth.generate import generate
from bop_cender.synth.write_dimo import DimoSpec
from bop_cender.synth.write_tless import TlessSpec

SPEC = TlessSpec(n_scenes=3, n_views=2, pbr_scenes=0, width=64, height=48, seed=4)


def digest(folder: Path) -> dict[str, str]:
    """Every file under ``folder`` (hidden ones included) by relative path: its bytes' hash."""
    return {
        p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def fresh(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("fresh")
    generate("tless", root, SPEC, progress=False)
    return root


def test_a_resume_regenerates_deleted_truncated_and_unmarked_scenes_byte_for_byte(fresh: Path, tmp_path: Path):
    resumed = tmp_path / "resumed"
    shutil.copytree(fresh, resumed)
    scenes = resumed / "test_primesense"
    assert all(scene_done(scenes / f"{s:06d}") for s in (1, 2, 3))
    shutil.rmtree(scenes / "000001")  # deleted
    depth = scenes / "000002" / "depth" / "000001.png"
    depth.write_bytes(depth.read_bytes()[:100])  # truncated: the folder is there, the scene is not done
    assert not scene_done(scenes / "000002")
    marker_path(scenes / "000003").unlink()  # renamed into place, interrupted before its marker was written
    (scenes / ".000003.partial").mkdir()  # and the leftovers of an interrupted writer
    (scenes / ".000003.partial" / "scene_gt.json").write_text("{")
    report = generate("tless", resumed, SPEC, progress=False)
    assert (report.written, report.skipped) == (3, 0)
    assert digest(resumed) == digest(fresh)


def test_a_finished_dataset_resumes_without_making_models_or_workers(fresh: Path, tmp_path: Path, monkeypatch):
    resumed = tmp_path / "resumed"
    shutil.copytree(fresh, resumed)

    def refused(*args, **kwargs):
        raise AssertionError("set-up work for a dataset that is complete")

    monkeypatch.setattr(generate_module, "_init_worker", refused)
    monkeypatch.setattr(layouts.TlessLayout, "write_models", refused)
    report = generate("tless", resumed, SPEC, workers=2, progress=False)
    assert (report.written, report.skipped) == (0, 3)
    assert digest(resumed) == digest(fresh)


def test_a_dimo_resume_drops_no_pile_for_a_done_folder(tmp_path: Path, monkeypatch):
    spec = DimoSpec(n_scenes=1, n_viewpoints=1, variants=(0, 17), width=48, height=40, seed=2, contact_sheets=False)
    generate("dimo", tmp_path / "a", spec, progress=False)
    calls = []
    make_pile = write_dimo.make_pile
    monkeypatch.setattr(write_dimo, "make_pile", lambda *a, **k: calls.append(1) or make_pile(*a, **k))
    before = digest(tmp_path / "a")
    shutil.rmtree(tmp_path / "a" / "sim_jaigo" / "000000_17")  # random poses: its own pile, and only that
    report = generate("dimo", tmp_path / "a", spec, progress=False)
    assert (report.written, report.skipped, len(calls)) == (1, 2, 1)
    assert digest(tmp_path / "a") == before


def test_the_cli_says_what_is_left_and_counts_only_that(tmp_path: Path, capsys):
    out = tmp_path / "ds"
    args = ["synth", "--layout", "tless", "--out", str(out), "--scenes", "3", "--views", "1", "--pbr-scenes", "0",
            "--no-contact-sheets"]  # fmt: skip
    assert main(args) == 0
    capsys.readouterr()
    shutil.rmtree(out / "test_primesense" / "000002")
    assert main(args) == 0
    err = capsys.readouterr().err  # not a terminal: plain lines, no carriage return, no escape code
    assert "[bop-cender] resuming: 2 of 3 scene folders done, 1 to go" in err
    assert "synth tless: 1/1 scene (100%) done" in err
    assert "1 scene folders written, 2 already complete" in err
    assert "\r" not in err and "\x1b" not in err
    fewer = [a if a != "3" else "2" for a in args]  # --scenes 2 into the folder of 3: the third is said, not hidden
    assert main(fewer) == 0
    assert "0 scene folders written, 2 already complete, 1 more of an earlier run kept" in capsys.readouterr().err


def test_two_writers_of_one_scene_each_rename_a_complete_folder(tmp_path: Path):
    """A second writer of a scene (a resumed synth beside the first one's surviving workers) neither empties nor
    deletes the first one's temporary folder: whichever finishes last, the scene folder holds all its files."""
    from bop_cender.synth.bop_files import scene_folder

    final = tmp_path / "train_pbr" / "000007"
    final.parent.mkdir(parents=True)
    files = [f"rgb/{i:06d}.jpg" for i in range(4)]

    def fill(folder: Path, tag: str) -> None:
        for rel in files:
            (folder / rel).parent.mkdir(parents=True, exist_ok=True)
            (folder / rel).write_text(tag)

    with scene_folder(final) as first:
        fill(first, "a")
        with scene_folder(final) as second:
            assert second != first and first.is_dir()
            fill(second, "b")
        assert scene_done(final) and {p.read_text() for p in (final / "rgb").iterdir()} == {"b"}
        assert all((first / rel).is_file() for rel in files)  # untouched by the second writer
    assert scene_done(final) and sorted(p.name for p in (final / "rgb").iterdir()) == [Path(f).name for f in files]
    assert not list(final.parent.glob(".*partial*"))


def test_leftovers_of_dead_writers_are_removed_and_a_live_writers_kept(tmp_path: Path):
    import os
    import subprocess
    import sys

    from bop_cender.synth.bop_files import scene_folder

    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead_pid = int(gone.stdout)
    parent = tmp_path / "test_primesense"
    dead = parent / f".000001.partial-{dead_pid}-0000abcd"
    old = parent / ".000001.partial"  # the name before per-writer folders
    live = parent / f".000001.partial-{os.getppid()}-0000beef"  # pytest's parent: alive
    for folder in (dead, old, live):
        folder.mkdir(parents=True)
        (folder / "scene_gt.json").write_text("{")
    with scene_folder(parent / "000001") as tmp:
        (tmp / "scene_gt.json").write_text("{}")
    assert not dead.exists() and not old.exists() and live.is_dir() and scene_done(parent / "000001")


def test_a_pool_worker_whose_synth_is_gone_takes_no_further_job(monkeypatch):
    class Exited(Exception):
        pass

    def fake_exit(code):
        raise Exited(code)

    ran = []
    monkeypatch.setattr(
        generate_module, "_WORKER", type("W", (), {"run": lambda self, root, job: ran.append(job) or 1})()
    )
    monkeypatch.setattr(generate_module.os, "_exit", fake_exit)
    monkeypatch.setattr(generate_module, "_PARENT_PID", generate_module.os.getppid())
    assert generate_module._run_job("root", ("test", 1)) == 1  # its parent is there: it works
    monkeypatch.setattr(generate_module, "_PARENT_PID", generate_module.os.getppid() + 100000)
    with pytest.raises(Exited):
        generate_module._run_job("root", ("test", 2))
    assert ran == [("test", 1)]


def test_a_folder_put_in_place_by_another_writer_during_the_rename_is_moved_aside(tmp_path: Path, monkeypatch):
    """Two writers finishing together: the other's complete folder lands on the scene between our move-aside and our
    rename; the rename is tried again and the scene ends complete, with no leftover."""
    from bop_cender.synth import bop_files

    final = tmp_path / "test_primesense" / "000002"
    final.mkdir(parents=True)
    (final / "old.txt").write_text("an older, unmarked folder")
    real_replace = os.replace
    calls = []

    def racing_replace(src, dst):
        calls.append((Path(src).name, Path(dst).name))
        if len(calls) == 2:  # our rename of tmp: the other writer got there just before
            Path(dst).mkdir()
            (Path(dst) / "theirs.txt").write_text("b")
        return real_replace(src, dst)

    monkeypatch.setattr(bop_files.os, "replace", racing_replace)
    with bop_files.scene_folder(final) as tmp:
        (tmp / "ours.txt").write_text("a")
    monkeypatch.setattr(bop_files.os, "replace", real_replace)
    assert sorted(p.name for p in final.iterdir()) == ["ours.txt"] and scene_done(final)
    assert not list(final.parent.glob(".*"))
    assert calls[0][1].endswith("-old0") and calls[2][1].endswith("-old1")  # the old folder, then theirs, aside
    assert calls[1] == calls[3] and calls[1][1] == "000002" and ".partial-" in calls[1][0]  # our rename, twice


def test_a_killed_generation_says_so_when_its_dataset_is_opened(tmp_path: Path, monkeypatch):
    """A synth killed after its first scene left a dataset that info and run read as complete (1 scene, no
    problem found)."""
    import warnings

    from bop_cender.data.registry import DatasetRequest, open_dataset
    from bop_cender.errors import DatasetWarning

    root = tmp_path / "killed"
    real = generate_module._run_job
    jobs = []

    def killed_after_one(*args):
        if jobs:
            raise KeyboardInterrupt
        jobs.append(1)
        return real(*args)

    monkeypatch.setattr(generate_module, "_run_job", killed_after_one)
    with pytest.raises(KeyboardInterrupt):
        generate("tless", root, SPEC, progress=False)
    with pytest.warns(DatasetWarning, match=r"bop_cender_synth.json: complete: bop-cender synth has not finished"):
        dataset = open_dataset(DatasetRequest("tless", root, "test"))
    assert len(dataset.scene_keys) >= 1
    monkeypatch.setattr(generate_module, "_run_job", real)
    generate("tless", root, SPEC, progress=False)  # the same command again completes it
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        open_dataset(DatasetRequest("tless", root, "test"))
