"""BOP'24/'25 detection scoring end to end: equal to the official toolkit on stored figures, the CLI, bad input."""

from __future__ import annotations

import csv
import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from bop_cender.cli import main
from bop_cender.data.registry import DatasetRequest, open_dataset
from bop_cender.errors import DatasetError, ResultsError, ResultsWarning
from bop_cender.eval.detection import BOP24_KEYS
from bop_cender.eval.ground_truth import collect_ground_truth
from bop_cender.eval.score_file import score_file
from bop_cender.eval.scoring_bop24 import SOURCE_ALL, SOURCE_BOP19, SOURCE_BOP24, score_detections, target_images
from bop_cender.results.bop_csv import write_bop_results
from bop_cender.results.files import write_run_sidecar
from bop_cender.synth.detection_rows import detection_rows
from tests.eval.scoring_data import row, target_instances

REFERENCE = json.loads((Path(__file__).parent / "fixtures" / "toolkit_reference_bop24.json").read_text())


@pytest.mark.parametrize("case", sorted(REFERENCE["cases"]))
def test_every_key_and_object_ap_equals_the_toolkits(small_fixture, small_dataset, case) -> None:
    """The toolkit's eval_bop24_pose.py on the same fixture and rows (scripts/make_bop24_reference.py): ties at the
    per-image cap, duplicates, negative scores, unknown object ids, non-target images, a missing scene, unknown times."""
    expected = REFERENCE["cases"][case]
    rows = detection_rows(small_fixture, **expected["args"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ResultsWarning)
        report = score_detections(rows, small_dataset, progress=False)
    for key in BOP24_KEYS:
        assert report.scores[key] == pytest.approx(expected["scores"][key], abs=1e-9), key
    for name, per_object in expected["object_aps"].items():
        ours = report.per_type[name]
        assert [str(o) for o in ours.objects] == list(per_object), name
        for obj, aps in per_object.items():
            assert [c.ap for c in ours.curves[int(obj)]] == pytest.approx(aps, abs=1e-9), (name, obj)


def test_the_edge_case_rows_exercise_every_rule(small_fixture, small_dataset) -> None:
    """The reference's edge case is not vacuous: rows are cut, ignored for each reason, and estimates left out."""
    rows = detection_rows(small_fixture, **REFERENCE["cases"]["edge"]["args"])
    report = score_detections(rows, small_dataset, progress=False)
    c = report.counts
    assert c.cut > 0 and c.not_target_image > 0 and c.object_not_in_image > c.unknown_object > 0
    assert c.gt_instances_hidden > 0
    left_out = sum(int(np.count_nonzero(r.status["mssd"] == -1)) for r in report.records)
    assert left_out > 0
    cut_scores = sorted(r.score for r in rows if (r.scene_id, r.im_id) == small_fixture.target_images[0])
    assert cut_scores.count(cut_scores[-100]) > 1  # equal scores straddle the cut


def test_ground_truth_poses_score_one_and_a_better_ordering_scores_higher(small_fixture, small_dataset) -> None:
    perfect = [row(s, i, o, 1.0, T, 0.5) for s, i, _g, o, T in target_instances(small_fixture)]
    assert all(v == 1.0 for k, v in score_detections(perfect, small_dataset, progress=False).scores.items()
               if k != "bop24_average_time_per_image")  # fmt: skip
    s, i, _g, o, T = target_instances(small_fixture)[0]
    wrong = T.copy()
    wrong[:3, 3] += 500.0
    last = score_detections([*perfect, row(s, i, o, 0.1, wrong, 0.5)], small_dataset, progress=False).scores
    first = score_detections([*perfect, row(s, i, o, 2.0, wrong, 0.5)], small_dataset, progress=False).scores
    assert last["bop24_mAP"] == 1.0 > first["bop24_mAP"]  # AP rewards ranking right poses above wrong ones


def test_target_images_come_from_the_bop24_file_then_the_bop19_file_then_all(small_fixture, tmp_path) -> None:
    root = tmp_path / "tless"
    shutil.copytree(small_fixture.root, root)
    ds = open_dataset(DatasetRequest("tless", root, "test"))
    gt = collect_ground_truth(ds, False)
    assert target_images(ds, gt).source == SOURCE_BOP19
    # BOP'24: the toolkit keys targets by image (a repeat is the same image); scenes grouped in order of appearance
    (root / "test_targets_bop24.json").write_text(
        json.dumps(
            [
                {"scene_id": 2, "im_id": 1},
                {"scene_id": 1, "im_id": 0},
                {"scene_id": 2, "im_id": 0},
                {"scene_id": 2, "im_id": 1, "obj_id": 3},
            ]
        )  # fmt: skip
    )
    ds = open_dataset(DatasetRequest("tless", root, "test"))  # the loader adds the BOP'24 images to the BOP'19 ones
    images = target_images(ds, collect_ground_truth(ds, False))
    assert images.source == SOURCE_BOP24 and images.keys == ((2, 1), (2, 0), (1, 0))
    assert (2, 1) not in gt.images  # not a BOP'19 target image: loaded only because the BOP'24 file names it
    (root / "test_targets_bop24.json").write_text(json.dumps([{"scene_id": 1, "im_id": "0"}]))
    with pytest.raises(DatasetError) as err:
        open_dataset(DatasetRequest("tless", root, "test"))
    assert err.value.field == "[0].im_id"
    (root / "test_targets_bop24.json").write_text(json.dumps([{"scene_id": 9, "im_id": 0}]))
    with pytest.raises(DatasetError, match="scene 9 has no folder"):
        open_dataset(DatasetRequest("tless", root, "test"))
    (root / "test_targets_bop24.json").write_text(
        json.dumps([{"scene_id": 2, "im_id": 1}, {"scene_id": 1, "im_id": 0}])
    )
    cut = target_images(open_dataset(DatasetRequest("tless", root, "test")), gt)  # loaded data without image (2, 1)
    assert cut.keys == ((1, 0),) and "1 of scenes not loaded (a partial run) left out" in cut.note
    (root / "test_targets_bop24.json").write_text(json.dumps([{"scene_id": 2, "im_id": 1}]))
    with pytest.raises(DatasetError, match="none of the target images"):
        target_images(open_dataset(DatasetRequest("tless", root, "test")), gt)
    (root / "test_targets_bop24.json").unlink()
    (root / "test_targets_bop19.json").unlink()
    assert target_images(open_dataset(DatasetRequest("tless", root, "test")), gt).source == SOURCE_ALL


def test_score_cli_bop24_writes_its_two_files_and_explains_the_figure(small_fixture, results_dir, capsys) -> None:
    csv_path = results_dir / "mine_tless-test.csv"
    write_bop_results(csv_path, detection_rows(small_fixture, **REFERENCE["cases"]["dense"]["args"]), sort=False)
    out = results_dir / "out"
    argv = ["score", str(csv_path), "--data-root", str(small_fixture.root), "--protocol", "bop24", "--out", str(out),
            "--no-progress"]  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ResultsWarning)
        assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "bop24_mAP" in printed and "cut beyond the 100 best-scored per image" in printed
    assert "MSSD mAP per object" in printed and "false positives" in printed
    data = json.loads((out / "scores_mine_tless-test_bop24.json").read_text())
    assert list(data)[:7] == list(BOP24_KEYS) and data["protocol"] == "bop24"
    expected = REFERENCE["cases"]["dense"]["scores"]
    assert all(data[k] == pytest.approx(expected[k], abs=1e-9) for k in BOP24_KEYS)
    curves = data["precision_recall"]["mssd"]
    assert len(data["precision_recall"]["recall_points"]) == 101 and all(len(c) == 10 for c in curves.values())
    assert set(data["per_object"]) == {"mssd", "mssd_mm", "mspd"}
    with (out / "detections_mine_tless-test_bop24.csv").open() as f:
        table = list(csv.DictReader(f))
    assert len(table) == data["metadata"]["counts"]["evaluated"]
    assert {"mssd_tp", "mssd_left_out", "mspd_tp"} <= set(table[0])


def test_the_sidecar_names_the_protocol_so_score_needs_no_flag(small_fixture, results_dir, capsys) -> None:
    csv_path = results_dir / "mine_tless-test.csv"
    perfect = [row(s, i, o, 1.0, T, 0.5) for s, i, _g, o, T in target_instances(small_fixture)]
    write_bop_results(csv_path, perfect)
    write_run_sidecar(csv_path, small_fixture.root, "tless", "test", {}, 0, {"protocol": "bop24"})
    assert main(["score", str(csv_path), "--no-progress"]) == 0
    assert "bop24_mAP" in capsys.readouterr().out
    assert (results_dir / "scores_mine_tless-test_bop24.json").is_file()
    assert main(["score", str(csv_path), "--protocol", "bop19", "--no-progress"]) == 0  # the flag wins
    assert (results_dir / "scores_mine_tless-test.json").is_file()
    write_run_sidecar(csv_path, small_fixture.root, "tless", "test", {}, 0, {"protocol": "bop99"})
    assert main(["score", str(csv_path), "--no-progress"]) != 0  # one error naming the sidecar and field
    assert "extra.protocol: expected one of bop19, bop24" in capsys.readouterr().err


def test_a_file_of_which_nothing_is_evaluated_is_refused(small_fixture, results_dir) -> None:
    csv_path = results_dir / "mine_tless-test.csv"
    _s, _i, _g, o, T = target_instances(small_fixture)[0]
    write_bop_results(csv_path, [row(77, 0, o, 1.0, T, 0.5), row(1, 0, 4, 1.0, T, 0.5)])  # no scene 77; 4 not in image
    with pytest.raises(ResultsError, match="0 of 2 rows are evaluated"), warnings.catch_warnings():
        warnings.simplefilter("ignore", ResultsWarning)
        score_file(csv_path, data_root=small_fixture.root, protocol="bop24", progress=False)
    assert not list(results_dir.glob("scores_*"))


def test_rows_the_toolkit_ignores_are_counted_and_said(small_fixture, small_dataset, results_dir) -> None:
    csv_path = results_dir / "mine_tless-test.csv"
    perfect = [row(s, i, o, 1.0, T, 0.5) for s, i, _g, o, T in target_instances(small_fixture)]
    write_bop_results(csv_path, [*perfect, row(1, 0, 999, 1.0, perfect[0].T_cam_model, 0.5)])
    with pytest.warns(ResultsWarning, match="1 of objects without a model"):
        scored = score_file(csv_path, data_root=small_fixture.root, protocol="bop24", progress=False)
    assert scored.report.counts.unknown_object == 1 and scored.report.scores["bop24_mAP"] == 1.0


def test_times_are_checked_on_the_rows_the_cap_keeps(small_fixture, results_dir) -> None:
    """A row beyond the cap may carry another time: the toolkit checks times after its cap (BOP'19 checks all)."""
    csv_path = results_dir / "mine_tless-test.csv"
    s, i, _g, o, T = target_instances(small_fixture)[0]
    rows = [row(s, i, o, 1.0 - k / 1000, T, 0.5) for k in range(100)] + [row(s, i, o, 0.0, T, 0.9)]
    _write_unchecked(csv_path, rows)
    scored = score_file(csv_path, data_root=small_fixture.root, protocol="bop24", progress=False, write=False)
    assert scored.report.counts.cut == 1 and scored.report.scores["bop24_average_time_per_image"] == 0.5
    with pytest.raises(ResultsError, match="time"):
        score_file(csv_path, data_root=small_fixture.root, protocol="bop19", progress=False, write=False)
    _write_unchecked(csv_path, [*rows[:50], row(s, i, o, 0.99, T, 0.9)])
    with pytest.raises(ResultsError, match="differ by more than 0.001 s"):
        score_file(csv_path, data_root=small_fixture.root, protocol="bop24", progress=False, write=False)


def _write_unchecked(path: Path, rows: list) -> None:
    """A results CSV as another tool might write it (our writer refuses times that differ within an image)."""
    text = lambda a: " ".join(repr(float(v)) for v in np.ravel(a))  # noqa: E731
    lines = [f"{r.scene_id},{r.im_id},{r.obj_id},{r.score!r},{text(r.R)},{text(r.t)},{r.time!r}" for r in rows]
    path.write_text("scene_id,im_id,obj_id,score,R,t,time\n" + "\n".join(lines) + "\n")
