"""End-to-end BOP'19 scoring on a small rendered T-LESS-layout fixture: predictable recalls, toolkit rules."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bop_cender.data.layout import MIN_VISIB_FRACT
from bop_cender.data.registry import DatasetRequest, open_dataset
from bop_cender.errors import ResultsError
from bop_cender.eval.ground_truth import collect_ground_truth
from bop_cender.eval.scoring import average_time_per_image, score_results
from bop_cender.eval.targets import SOURCE_FILE, SOURCE_RENDERED, resolve_targets
from bop_cender.eval.visibility import rendered_visib_fracts
from bop_cender.meshes import MeshCache
from bop_cender.results.bop_csv import write_bop_results
from bop_cender.synth.regression_fixture import BuiltFixture
from tests.eval.scoring_data import gt_rows, row, target_instances

WEDGE, CYLINDER, BOX = 3, 1, 2


def _all_recalls(report) -> np.ndarray:
    return np.concatenate([report.mssd_recalls, report.mspd_recalls, report.vsd_recalls.reshape(-1)])


def test_gt_poses_give_every_recall_one(small_fixture: BuiltFixture, small_dataset) -> None:
    rows = gt_rows(small_fixture)
    report = score_results(rows, small_dataset, progress=False)
    assert np.all(_all_recalls(report) == 1.0)
    assert report.scores == {k: 1.0 for k in report.scores}
    counts = report.metadata.counts
    assert counts.evaluated == len(rows) == counts.target_instances
    assert counts.not_target == counts.beyond_top_n == 0
    assert report.metadata.targets_source == SOURCE_FILE
    assert report.metadata.mspd_width == 720  # the toolkit's T-LESS constant, not the 240 px of the images
    assert report.metadata.time_per_image == 0.5
    for r in report.records:  # each estimate matched its own GT at every threshold, with zero error
        assert np.all(r.mssd_match == r.mssd_match[0]) and r.mssd_match[0] >= 0
        j = int(np.flatnonzero(r.gt_ids == r.mssd_match[0])[0])
        assert r.mssd_mm[j] < 1e-9 and r.mspd_px[j] < 1e-9 and np.all(r.vsd[j] == 0.0)


@pytest.mark.parametrize(("kind", "expected_at_5pct"), [("t_4.5%", "all"), ("t_5.5%", "all_but_wedges")])
def test_translations_straddling_the_mssd_threshold(small_fixture, small_dataset, kind, expected_at_5pct) -> None:
    """The wedge has no symmetry: a translation by d gives MSSD = |d| exactly, 4.5 % in, 5.5 % out at 5 %."""
    rows = gt_rows(small_fixture, {WEDGE: kind})
    report = score_results(rows, small_dataset, progress=False)
    n = len(rows)
    n_wedges = sum(1 for r in rows if r.obj_id == WEDGE)
    assert 0 < n_wedges < n
    expected = n if expected_at_5pct == "all" else n - n_wedges
    assert report.mssd_recalls[0] == pytest.approx(expected / n, abs=0)
    assert np.all(report.mssd_recalls[1:] == 1.0)
    fraction = float(kind[2:-1]) / 100
    for r in report.records:
        if r.obj_id == WEDGE:
            assert r.mssd.min() == pytest.approx(fraction, abs=1e-12)


def test_symmetric_estimates_score_as_gt(small_fixture, small_dataset) -> None:
    """Cylinders rotated about their axis (continuous symmetry), boxes turned by a discrete symmetry."""
    rows = gt_rows(small_fixture, {CYLINDER: "symmetric", BOX: "symmetric"}, seed=3)
    report = score_results(rows, small_dataset, progress=False)
    assert np.all(report.mssd_recalls == 1.0) and np.all(report.mspd_recalls == 1.0)
    assert report.vsd_recalls[:, -1].min() == 1.0  # at the loosest VSD threshold, every tau
    for r in report.records:
        best = r.mssd.min()
        # 315 samples of the continuous symmetry: at most ~1 % of the radius off (r = 30 mm, diameter ~ 89 mm)
        assert best < (0.01 * 30 / 80 if r.obj_id == CYLINDER else 1e-9)


def test_duplicates_and_non_target_estimates_are_ignored(small_fixture, small_dataset) -> None:
    base = gt_rows(small_fixture)
    reference = score_results(base, small_dataset, progress=False).scores
    extra = []
    for s, i, _g, o, T in target_instances(small_fixture)[:4]:
        extra.append(row(s, i, o, 0.5, T @ _shift(40.0), 0.5))  # a worse duplicate with a lower score: cut
    non_target_images = sorted(set(small_fixture.gt) - {(t["scene_id"], t["im_id"]) for t in small_fixture.targets})
    assert non_target_images
    for s, i in non_target_images:
        extra.append(row(s, i, small_fixture.gt[(s, i)][0][1], 0.9, small_fixture.gt[(s, i)][0][2], 0.5))
    s, i, _g, _o, T = target_instances(small_fixture)[0]
    extra.append(row(s, i, 4, 0.99, T, 0.5))  # object 4 has a model but no instance: never a target
    report = score_results(base + extra, small_dataset, progress=False)
    assert report.scores == reference
    counts = report.metadata.counts
    assert counts.beyond_top_n == 4
    assert counts.not_target == len(non_target_images) + 1
    assert counts.unselected_images == len(non_target_images)


def test_a_better_ranked_duplicate_replaces_the_estimate(small_fixture, small_dataset) -> None:
    """Top-n keeps the highest scores: a far-off estimate ranked first takes the only slot of a single instance."""
    base = gt_rows(small_fixture)
    singles = [t for t in target_instances(small_fixture) if sum(u[:2] == t[:2] and u[3] == t[3]
                                                                   for u in target_instances(small_fixture)) == 1]  # fmt: skip
    s, i, _g, o, T = singles[0]
    report = score_results([*base, row(s, i, o, 2.0, T @ _shift(200.0), 0.5)], small_dataset, progress=False)
    assert report.mssd_recalls[-1] == pytest.approx((len(base) - 1) / len(base), abs=0)
    assert report.metadata.counts.beyond_top_n == 1


def test_unknown_scene_image_or_object_is_an_error_naming_the_line(small_fixture, results_dir) -> None:
    from bop_cender.eval.score_file import score_file

    rows = gt_rows(small_fixture)[:2]
    T = np.eye(4)
    T[2, 3] = 700.0
    bad = [row(1, 99, 1, 1.0, T, 0.5), row(42, 0, 1, 1.0, T, 0.5)]
    csv = results_dir / "m_tless-test.csv"
    write_bop_results(csv, rows + bad, sort=False)
    with pytest.raises(ResultsError) as info:
        score_file(csv, data_root=small_fixture.root, progress=False)
    text = info.value.format()
    assert "line 4: im_id: scene 1 has no image 99" in text
    assert "line 5: scene_id: no scene 42" in text
    assert "line 2" not in text and "line 3" not in text


def test_n_top_zero_evaluates_every_estimate(small_fixture, small_dataset) -> None:
    base = gt_rows(small_fixture)
    s, i, _g, o, T = target_instances(small_fixture)[0]
    report = score_results([*base, row(s, i, o, 0.1, T @ _shift(300.0), 0.5)], small_dataset, n_top=0, progress=False)
    assert report.metadata.counts.evaluated == len(base) + 1
    assert np.all(report.mssd_recalls == 1.0)  # the extra estimate matches nothing and costs nothing


def test_average_time_per_image() -> None:
    T = np.eye(4)
    rows = [row(1, 0, 1, 1.0, T, 0.2), row(1, 0, 2, 1.0, T, 0.2), row(1, 1, 1, 1.0, T, 0.6)]
    assert average_time_per_image(rows) == pytest.approx(0.4)
    assert average_time_per_image([*rows, row(1, 2, 1, 1.0, T, -1.0)]) is None


def test_dimo_layout_without_depth_has_no_vsd_and_computes_targets(small_fixture, dimo_copy) -> None:
    """The same scene in DIMO layout: targets from rendered visibility equal the fixture's 0.1 rule; no VSD, no AR."""
    ds = open_dataset(DatasetRequest("dimo", dimo_copy, "real"))
    gt = collect_ground_truth(ds, progress=False)
    targets = resolve_targets(
        ds.bop19_targets(), gt, ds.target_obj_ids, lambda: rendered_visib_fracts(list(gt), MeshCache(ds.models), False)
    )
    assert targets.source == SOURCE_RENDERED
    expected = set()
    for im in range(small_fixture.spec.n_images):
        fracts = small_fixture.visib[(1, im)]
        for (g, _o, _T), f in zip(small_fixture.gt[(1, im)], fracts, strict=True):
            assert targets.visib[(0, im)][g] == pytest.approx(f, abs=1e-12)
        for o in {o for g, o, _T in small_fixture.gt[(1, im)] if fracts[g] >= MIN_VISIB_FRACT}:
            n = sum(1 for g, oo, _T in small_fixture.gt[(1, im)] if oo == o and fracts[g] >= MIN_VISIB_FRACT)
            expected.add((0, im, o, n))
    assert {(t.scene_id, t.im_id, t.obj_id, t.inst_count) for t in targets.targets} == expected
    assert all(t.obj_id < 100 for t in targets.targets)  # carriers occlude but are never targets

    rows = [
        row(0, im, o, 1.0, T, -1.0)
        for im in range(small_fixture.spec.n_images)
        for g, o, T in small_fixture.gt[(1, im)]
        if small_fixture.visib[(1, im)][g] >= MIN_VISIB_FRACT
    ]
    report = score_results(rows, ds, progress=False)
    assert report.scores["AR"] is None and report.scores["AR_VSD"] is None and report.vsd_recalls is None
    assert report.scores["AR_MSSD"] == 1.0 and report.scores["AR_MSPD"] == 1.0
    assert report.metadata.vsd_delta is None and report.metadata.time_per_image is None
    assert report.metadata.mspd_width == 240  # DIMO is unknown to the toolkit: the images' width
    assert any("no test depth" in n for n in report.notes)


def _shift(mm: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = mm
    return T


def test_mspd_width_follows_the_split_type_of_the_folder(small_fixture, tmp_path) -> None:
    import shutil

    from bop_cender.data.bop import open_bop

    root = tmp_path / "hb"
    shutil.copytree(small_fixture.root, root, symlinks=True)
    (root / "test_primesense").rename(root / "test_kinect")  # HB's Kinect split: the toolkit's width is 1920
    ds = open_bop(root, "test", name="hb", split_type="kinect", model_type="cad")
    report = score_results(gt_rows(small_fixture), ds, progress=False)
    assert report.metadata.mspd_width == 1920, report.metadata.mspd_width_source


def test_ground_truth_is_what_the_loader_read(small_dataset) -> None:
    """Per-image GT poses are the stored scene_gt.json values, bit for bit, read once by the loader."""
    import json

    from bop_cender.eval.ground_truth import POSES_STORED, collect_ground_truth
    from bop_cender.geometry.poses import pose_from_bop

    gt = collect_ground_truth(small_dataset, progress=False)
    assert gt.pose_source == POSES_STORED and small_dataset.split_folder == "test_primesense"
    for scene in small_dataset.scenes():
        stored = json.loads((small_dataset.split_dir / scene.scene_id / "scene_gt.json").read_text())
        for obj in scene.gt:
            for im, g in obj.gt_ids.items():
                entry = stored[str(im)][g]
                assert np.array_equal(obj.T_cam_model[im], pose_from_bop(entry["cam_R_m2c"], entry["cam_t_m2c"]))


def test_a_targets_file_that_asks_for_more_instances_than_the_ground_truth_is_refused(small_fixture, tmp_path) -> None:
    """inst_count above its object's GT instances in the image: not this dataset's targets (or damaged); the
    top-n cut would keep estimates no instance can match. One error naming the file, at scoring."""
    import shutil

    from bop_cender.data.layout import TARGETS_FILE
    from bop_cender.errors import DatasetError
    from bop_cender.eval.score_file import score_file

    root = tmp_path / "tless"
    shutil.copytree(small_fixture.root, root)
    targets = json.loads((root / TARGETS_FILE).read_text())
    targets[0]["inst_count"] += 5
    (root / TARGETS_FILE).write_text(json.dumps(targets))
    csv = tmp_path / "m_tless-test.csv"
    write_bop_results(csv, gt_rows(small_fixture))
    with pytest.raises(DatasetError, match=f"{TARGETS_FILE}: inst_count: the target of scene") as info:
        score_file(csv, data_root=root, progress=False, write=False, render_process=False)
    assert "instance(s) of that object" in str(info.value)


def test_a_repeated_target_is_refused_when_the_dataset_opens(small_fixture, tmp_path) -> None:
    import shutil

    from bop_cender.data.layout import TARGETS_FILE
    from bop_cender.data.targets_file import read_targets
    from bop_cender.errors import DatasetError

    root = tmp_path / "tless"
    shutil.copytree(small_fixture.root, root)
    targets = json.loads((root / TARGETS_FILE).read_text())
    (root / TARGETS_FILE).write_text(json.dumps([*targets, targets[0]]))
    message = rf"{TARGETS_FILE}: \[{len(targets)}\]: repeats the target of scene .* \(first at \[0\]\)"
    with pytest.raises(DatasetError, match=message):
        open_dataset(DatasetRequest("tless", root, "test"))
    with pytest.raises(DatasetError, match=message):
        read_targets(root / TARGETS_FILE)


@pytest.mark.parametrize("t", [1e300, -1e200, 1e154])
def test_a_finite_but_absurd_translation_is_a_miss_without_numpy_warnings(small_fixture, small_dataset, t) -> None:
    """t = 1e300 mm is a finite number in a CSV; every error of it is infinite (a miss), said without overflow
    warnings leaking out of MSSD, MSPD or VSD."""
    import warnings

    base = gt_rows(small_fixture)
    first = base[0]
    absurd = row(first.scene_id, first.im_id, first.obj_id, 1.0, np.c_[first.R, np.full(3, t)], 0.5)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        report = score_results([absurd, *base[1:]], small_dataset, progress=False)
    assert report.mssd_recalls[-1] == pytest.approx((len(base) - 1) / len(base), abs=0)
    assert report.vsd_recalls is not None and np.nanmax(report.vsd_recalls) < 1.0
