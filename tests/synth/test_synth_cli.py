"""``bop-cender synth`` and ``bop-cender info`` through the command line: a tiny dataset written, resumed, described."""

from __future__ import annotations

from pathlib import Path

from bop_cender.cli import main


def test_synth_writes_resumes_and_info_describes(tmp_path: Path, capsys) -> None:
    out = tmp_path / "tless"
    args = ["synth", "--layout", "tless", "--out", str(out), "--scenes", "1", "--views", "2", "--pbr-scenes", "0",
            "--no-contact-sheets"]  # fmt: skip
    assert main(args) == 0
    assert "1 scene folders written, 0 already complete" in capsys.readouterr().err  # summary beside the bar
    assert main(args) == 0  # resumed: nothing to do
    assert "0 scene folders written, 1 already complete" in capsys.readouterr().err
    assert main(["info", "--dataset", "tless", "--data-root", str(out), "--split", "test"]) == 0
    assert "tless" in capsys.readouterr().out


def test_synth_into_a_path_that_cannot_be_a_folder_is_one_error(tmp_path: Path, capsys) -> None:
    (tmp_path / "a_file").write_text("x")
    code = main(["synth", "--layout", "tless", "--out", str(tmp_path / "a_file" / "ds"), "--scenes", "1"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: ") and "Traceback" not in err and len(err.strip().splitlines()) == 1
