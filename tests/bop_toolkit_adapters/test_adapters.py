"""The seam to the official BOP toolkit: exports it can read unchanged, and a cross-check that is optional.

The cross-check against the real toolkit runs only where ``BOP_TOOLKIT_DIR`` names a checkout (with
vispy/pypng importable and ``EGL_PLATFORM=surfaceless`` for VSD); it is marked slow.
"""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
from dataclasses import replace
from pathlib import Path

import pytest

from bop_cender.cli import main
from bop_cender.data.registry import DatasetRequest, open_dataset
from bop_cender.data.targets_file import read_targets
from bop_cender.results.bop_csv import write_bop_results
from bop_toolkit_adapters.export import export_for_toolkit
from bop_toolkit_adapters.runtime import ToolkitUnavailable, import_toolkit
from tests.eval.scoring_data import gt_rows, row


def test_export_tless_in_the_toolkit_layout(small_fixture, small_dataset, tmp_path: Path) -> None:
    csv = tmp_path / "cendernet_tless-test.csv"
    write_bop_results(csv, gt_rows(small_fixture))
    export = export_for_toolkit(small_dataset, csv, tmp_path / "tk", progress=False)
    assert (export.dataset, export.split, export.split_type, export.split_folder) == (
        "tless",
        "test",
        None,
        "test_primesense",
    )
    assert (
        export.result_filename == "cendernet_tless-test.csv"
        and (export.results_path / export.result_filename).is_file()
    )
    assert export.known_to_toolkit and export.mspd_width == 720 and export.im_size == (240, 180)
    base = export.datasets_path / "tless"
    assert read_targets(base / "test_targets_bop19.json") == read_targets(
        small_fixture.root / "test_targets_bop19.json"
    )
    assert (base / "models_eval" / "models_info.json").is_file()
    src = small_fixture.root / "test_primesense" / "000001"
    dst = base / "test_primesense" / "000001"
    exported = json.loads((dst / "scene_gt.json").read_text())
    original = json.loads((src / "scene_gt.json").read_text())
    assert exported and all(exported[k] == original[k] for k in exported)  # entries as stored, bit for bit
    for im in exported:
        assert (dst / "depth" / f"{int(im):06d}.png").resolve() == (src / "depth" / f"{int(im):06d}.png").resolve()


def test_export_dimo_registers_what_the_toolkit_lacks(small_fixture, dimo_copy, tmp_path: Path) -> None:
    ds = open_dataset(DatasetRequest("dimo", dimo_copy, "real"))
    csv = tmp_path / "cendernet_dimo-real.csv"
    write_bop_results(
        csv, [row(0, r.im_id, r.obj_id, 1.0, r.T_cam_model) for r in gt_rows(small_fixture) if r.scene_id == 1]
    )
    export = export_for_toolkit(ds, csv, tmp_path / "tk", progress=False)
    assert not export.known_to_toolkit and export.vsd_delta is None and export.mspd_width == 240
    scene = export.datasets_path / "dimo" / "real" / "000000"
    info = json.loads((scene / "scene_gt_info.json").read_text())  # DIMO has none: written from rendered visibility
    assert set(info) == {"0", "1", "2"} and all("visib_fract" in e for e in info["0"])
    assert read_targets(export.datasets_path / "dimo" / "test_targets_bop19.json")
    assert 100 in export.obj_ids and 101 in export.obj_ids  # carriers' models are there (as occluders)


def test_crosscheck_without_the_toolkit_says_so(small_fixture, tmp_path: Path, capsys) -> None:
    if importlib.util.find_spec("bop_toolkit_lib") is not None:
        pytest.skip("bop_toolkit_lib is installed in this environment")
    with pytest.raises(ToolkitUnavailable, match="not importable"):
        import_toolkit(tmp_path / "nowhere")
    csv = tmp_path / "cendernet_tless-test.csv"
    write_bop_results(csv, gt_rows(small_fixture)[:3])
    code = main(
        ["crosscheck", str(csv), "--toolkit", str(tmp_path / "nowhere"), "--data-root", str(small_fixture.root)]
    )
    assert code == 2  # a toolkit was named and is not there
    err = capsys.readouterr().err
    assert err.startswith("error: crosscheck not run: the BOP toolkit (bop_toolkit_lib) is not importable")
    # none asked for: still not a pass (a CI script must not read a skipped cross-check as agreement)
    assert main(["crosscheck", str(csv), "--data-root", str(small_fixture.root)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: crosscheck not run: ") and "pass --toolkit DIR" in err and err.count("\n") == 1


@pytest.mark.slow
def test_crosscheck_with_the_official_toolkit(small_fixture, tmp_path: Path, capsys) -> None:
    toolkit = os.environ.get("BOP_TOOLKIT_DIR")
    if not toolkit:
        pytest.skip("set BOP_TOOLKIT_DIR to a checkout of thodan/bop_toolkit to run the cross-check")
    from bop_toolkit_adapters.crosscheck import crosscheck_file

    csv = tmp_path / "cendernet_tless-test.csv"
    write_bop_results(csv, gt_rows(small_fixture, {3: "t_5.5%", 1: "symmetric"}))
    check = crosscheck_file(csv, tmp_path / "cc", toolkit, data_root=small_fixture.root, progress=False)
    for key, diff in check.score_diffs.items():
        assert diff is None or diff == 0.0, key
    assert check.pair_diffs["mssd"] < 1e-9 and check.pair_diffs["mspd"] < 1e-9


def test_pairs_that_differ_from_the_toolkit_are_listed_largest_first(small_fixture, small_dataset, tmp_path) -> None:
    from bop_cender.eval.scoring import score_results
    from bop_toolkit_adapters.crosscheck import (
        LIST_TOLERANCE,
        Crosscheck,
        compare_pair_errors,
        format_crosscheck,
        pair_differences,
        write_pair_differences,
    )
    from bop_toolkit_adapters.export import ToolkitExport
    from bop_toolkit_adapters.runtime import ToolkitScores

    report = score_results(gt_rows(small_fixture, {3: "t_5.5%", 1: "far"}), small_dataset, progress=False)
    toolkit = ToolkitScores(errors={"mssd": {}, "mspd": {}, "vsd": {}})
    for r in report.records:  # the toolkit's numbers: ours, then a few changed below
        for j, gt_id in enumerate(r.gt_ids.tolist()):
            key = (r.scene_id, r.im_id, r.obj_id, r.est_id, gt_id)
            toolkit.errors["mssd"][key] = [float(r.mssd_mm[j])]
            toolkit.errors["mspd"][key] = [float(r.mspd_px[j])]
            toolkit.errors["vsd"][key] = [float(v) for v in r.vsd[j]]
    keys = sorted(k for k, v in toolkit.errors["mssd"].items() if v[0] < float("inf"))
    assert any(v == [float("inf")] for v in toolkit.errors["mssd"].values())  # early-outs: inf == inf is no difference
    toolkit.errors["vsd"][keys[0]][4] += 0.002  # one pixel's vote at one tau
    toolkit.errors["mssd"][keys[1]][0] += 1e-9  # float noise: below the listing tolerance
    toolkit.errors["mspd"][keys[2]][0] += 0.5
    del toolkit.errors["mspd"][keys[3]]  # a pair only we computed: counted as missing, not listed

    differences = pair_differences(report, toolkit)
    assert [(d.error, d.max_diff) for d in differences] == [("mspd", pytest.approx(0.5)), ("vsd", pytest.approx(0.002))]
    assert (differences[1].scene_id, differences[1].im_id, differences[1].obj_id) == keys[0][:3]
    assert differences[1].toolkit[4] - differences[1].ours[4] == pytest.approx(0.002)
    diffs = compare_pair_errors(report, toolkit)
    assert diffs["mssd"] == pytest.approx(1e-9, rel=1e-3) and diffs["missing_mspd"] == 1
    assert LIST_TOLERANCE["mssd"] > diffs["mssd"]

    path = tmp_path / "pair_differences.csv"
    write_pair_differences(path, differences)
    lines = path.read_text().splitlines()
    assert lines[0] == "error,scene_id,im_id,obj_id,est_id,gt_id,max_abs_diff,ours,toolkit"
    assert lines[1].startswith("mspd,") and lines[2].startswith("vsd,") and len(lines) == 3
    assert len(lines[2].split(",")[7].split()) == 10  # VSD: one value per tau

    export = ToolkitExport.__new__(ToolkitExport)  # format_crosscheck only names its folder
    object.__setattr__(export, "out_dir", tmp_path)
    check = Crosscheck(report, toolkit, export, {}, {}, diffs, [], differences)
    text = format_crosscheck(check)
    assert "VSD   pairs differing by more than 0: 1" in text and "MSSD  pairs differing by more than 1e-06: 0" in text


def test_a_failing_toolkit_script_is_one_error_naming_it(tmp_path) -> None:
    from bop_toolkit_adapters.runtime import ToolkitRunError, _run

    (tmp_path / "exits.py").write_text("import sys\nprint('bad input')\nsys.exit(3)\n")
    (tmp_path / "raises.py").write_text("raise ValueError('no such scene')\n")
    with pytest.raises(ToolkitRunError, match=r"exits.py: exited with 3: bad input"):
        _run(tmp_path / "exits.py", [], quiet=True)
    with pytest.raises(ToolkitRunError, match=r"raises.py: failed: ValueError: no such scene"):
        _run(tmp_path / "raises.py", [], quiet=True)


def _fake_toolkit(root: Path, misc: str) -> Path:
    """A stand-in for a toolkit checkout: ``bop_toolkit_lib`` with ``misc`` as its misc.py, an errors script that
    writes no error and a scores script that writes the recall in ``$RECALL``."""
    lib = root / "bop_toolkit_lib"
    (root / "scripts").mkdir(parents=True)
    lib.mkdir()
    (lib / "__init__.py").write_text("")
    (lib / "misc.py").write_text(misc)
    (lib / "inout.py").write_text("import json\ndef load_json(p, keys_to_int=False):\n    return json.load(open(p))\n")
    (lib / "dataset_params.py").write_text(
        "def get_split_params(*a, **k): return {}\ndef get_model_params(*a, **k): return {}\n"
    )
    (root / "scripts" / "eval_calc_errors.py").write_text("")
    (root / "scripts" / "eval_calc_scores.py").write_text(
        "import os, sys\n"
        "a = dict(x.split('=', 1) for x in sys.argv[1:] if x.startswith('--'))\n"
        "th = [v for k, v in a.items() if k.startswith('--correct_th')][0]\n"
        "p = os.path.join(a['--eval_path'], a['--error_dir_paths'])\n"
        "os.makedirs(p, exist_ok=True)\n"
        "open(os.path.join(p, 'scores_th=' + th + '.json'), 'w').write('{\"recall\": %s}' % os.environ['RECALL'])\n"
    )
    return root


_MISC = "def get_error_signature(e, n, **k): return f'error={e}_ntop={n}'\ndef get_score_signature(th, v): return 'th=' + str(th[0])\n"


def test_a_crosscheck_that_disagrees_or_cannot_read_the_toolkit_is_never_exit_0(small_fixture, tmp_path) -> None:
    """A fuzz found exit 0 beside an AR 6 apart and "0 pairs compared", a traceback from an incompatible toolkit,
    and the scores and export left behind by a failed one. In a subprocess: the fake toolkit stays out of this one."""
    import subprocess
    import sys

    csv = tmp_path / "gt_tless-test.csv"
    write_bop_results(csv, gt_rows(small_fixture))
    good, broken = _fake_toolkit(tmp_path / "tk", _MISC), _fake_toolkit(tmp_path / "old", "")
    root = Path(__file__).resolve().parents[2]

    def crosscheck(toolkit: Path, recall: str) -> tuple[int, str, str]:
        out = tmp_path / "cc"
        shutil.rmtree(out, ignore_errors=True)
        argv = [sys.executable, "-m", "bop_cender.cli", "crosscheck", str(csv), "--toolkit", str(toolkit),
                "--data-root", str(small_fixture.root), "--no-vsd", "--no-progress", "--out", str(out)]  # fmt: skip
        env = {**os.environ, "RECALL": recall, "PYTHONPATH": str(root)}
        done = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=300, cwd=tmp_path)
        assert "Traceback" not in done.stdout + done.stderr, done.stderr[-2000:]
        return done.returncode, done.stdout, done.stderr

    code, out, _ = crosscheck(good, "1.0")  # every recall 1, as ours: but no pair (the stand-in writes no error)
    assert code == 1 and "AR" not in out.split("verdict")[1] and "computed by one side only" in out
    code, out, _ = crosscheck(good, "0.5")
    assert code == 1 and "verdict: bop-cender and the BOP toolkit DISAGREE" in out
    assert "AR_MSSD differs by 0.5 (more than 1e-06)" in out and "pair(s) computed by one side only" in out
    for toolkit, recall, message in ((good, "NaN", "recall: expected a recall in [0, 1], got nan"),
                                     (good, "7", "recall: expected a recall in [0, 1], got 7"),
                                     (broken, "0.5", "an incompatible version?")):  # fmt: skip
        code, _, err = crosscheck(toolkit, recall)
        assert code == 2 and message in err and err.count("\n") == 1, err
        assert not (tmp_path / "cc").exists()  # nothing half-written


def test_the_verdict_lists_every_disagreement(small_fixture, small_dataset, tmp_path) -> None:
    from bop_cender.eval.scoring import score_results
    from bop_toolkit_adapters.crosscheck import Crosscheck, compare_pair_errors
    from bop_toolkit_adapters.runtime import ToolkitScores

    report = score_results(gt_rows(small_fixture, {3: "t_5.5%"}), small_dataset, progress=False)
    toolkit = ToolkitScores(errors={"mssd": {}, "mspd": {}})
    for r in report.records:
        for j, gt_id in enumerate(r.gt_ids.tolist()):
            key = (r.scene_id, r.im_id, r.obj_id, r.est_id, gt_id)
            toolkit.errors["mssd"][key] = [float(r.mssd_mm[j])]
            toolkit.errors["mspd"][key] = [float(r.mspd_px[j])]
    same = dict(report.scores)

    def check(theirs: dict) -> list[str]:
        return Crosscheck(report, toolkit, None, theirs, {}, compare_pair_errors(report, toolkit), []).disagreements()

    assert check(same) == []
    assert check({**same, "AR_MSSD": same["AR_MSSD"] + 1e-5}) == ["AR_MSSD differs by 1e-05 (more than 1e-06)"]
    tied = None if same["AR_VSD"] is None else same["AR_VSD"] + 5e-4  # the renderers' ties: within tolerance
    assert check({**same, "AR_VSD": tied}) == []
    assert check({**same, "AR_MSPD": float("nan")})[0].startswith("AR_MSPD: bop-cender ")
    assert check({**same, "AR": None, "AR_VSD": None})[0].startswith("AR: bop-cender ")  # VSD not skipped: missing
    toolkit.skipped["vsd"] = "skipped on request"  # --no-vsd, or no renderer: AR and AR_VSD are not judged
    assert check({**same, "AR": None, "AR_VSD": None}) == []
    ours_nan = Crosscheck(replace(report, scores={**same, "AR_MSSD": float("nan")}), toolkit, None, same, {},
                          compare_pair_errors(report, toolkit), [])  # fmt: skip
    assert ours_nan.disagreements()[0].startswith("AR_MSSD: bop-cender n/a")
    del toolkit.errors["mspd"][next(iter(toolkit.errors["mspd"]))]
    assert check(same) == ["MSPD: 1 (estimate, GT) pair(s) computed by one side only"]


def test_crosscheck_bop24_without_the_toolkit_says_so(small_fixture, tmp_path: Path, capsys) -> None:
    if importlib.util.find_spec("bop_toolkit_lib") is not None:
        pytest.skip("bop_toolkit_lib is installed in this environment")
    csv = tmp_path / "cendernet_tless-test.csv"
    write_bop_results(csv, gt_rows(small_fixture)[:3])
    argv = ["crosscheck", str(csv), "--protocol", "bop24", "--toolkit", str(tmp_path / "nowhere"), "--data-root",
            str(small_fixture.root), "--out", str(tmp_path / "cc")]  # fmt: skip
    assert main(argv) == 2
    assert capsys.readouterr().err.startswith("error: crosscheck not run: the BOP toolkit")
    assert not (tmp_path / "cc").exists()  # nothing half-written


def test_bop24_export_lists_our_target_images_and_target_objects(small_fixture, dimo_copy, tmp_path: Path) -> None:
    from bop_toolkit_adapters.bop24 import export_bop24

    csv = tmp_path / "cendernet_dimo-real.csv"
    write_bop_results(csv, [row(0, 0, 1, 1.0, __import__("numpy").eye(4), 0.5)])
    ds = open_dataset(DatasetRequest("dimo", dimo_copy, "real"))
    export = export_bop24(ds, csv, tmp_path / "export", progress=False)
    assert 100 not in export.obj_ids and 1 in export.obj_ids  # DIMO's carriers are not detection targets
    listed = json.loads((export.datasets_path / "dimo" / "test_targets_bop24.json").read_text())
    assert listed and all(set(e) == {"scene_id", "im_id"} for e in listed)


@pytest.mark.slow
def test_crosscheck_bop24_with_the_official_toolkit(small_fixture, tmp_path: Path, capsys) -> None:
    """The toolkit's own eval_bop24_pose.py on rows that exercise every rule: every key and per-object AP within
    1e-9 (``scripts/make_bop24_reference.py`` stores these figures for the runs without a toolkit)."""
    toolkit = os.environ.get("BOP_TOOLKIT_DIR")
    if not toolkit:
        pytest.skip("set BOP_TOOLKIT_DIR to a checkout of thodan/bop_toolkit to run the cross-check")
    from bop_cender.synth.detection_rows import detection_rows

    csv = tmp_path / "cendernet_tless-test.csv"
    write_bop_results(csv, detection_rows(small_fixture, seed=11, crowded=120), sort=False)
    argv = ["crosscheck", str(csv), "--protocol", "bop24", "--toolkit", toolkit, "--data-root",
            str(small_fixture.root), "--out", str(tmp_path / "cc"), "--no-progress"]  # fmt: skip
    with pytest.warns(Warning):
        assert main(argv) == 0
    assert "verdict: bop-cender and the BOP toolkit agree" in capsys.readouterr().out
