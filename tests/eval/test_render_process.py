"""VSD renders in threads or in a render process: the same crops and VSD either way, a dead child replaced.

torch is imported in this test process, so the render processes started here are spawned (a fork after
torch has run can hang in MKL's allocator); the CLI forks its child before importing torch, which the
cold-start test runs in a subprocess.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from bop_cender.data.bop_io import load_depth
from bop_cender.eval import render_process
from bop_cender.eval.ground_truth import collect_ground_truth
from bop_cender.eval.matching import select_top_n
from bop_cender.eval.pair_vsd import pair_vsd, plan_renders
from bop_cender.eval.render_process import RenderJob, RenderProcess, ThreadRenderer, render_job
from bop_cender.eval.score_file import score_file
from bop_cender.eval.scoring import _pairs
from bop_cender.eval.targets import resolve_targets
from bop_cender.eval.vsd import VSD_TAUS, vsd
from bop_cender.meshes import MeshArrays, MeshCache
from bop_cender.render.rasterizer import render_objects_separately
from bop_cender.results.bop_csv import write_bop_results
from tests.eval.scoring_data import gt_rows, row

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture()
def scene_pairs(small_fixture, small_dataset):
    """Pairs of the small fixture's estimates (GT poses perturbed, so VSD is neither 0 nor 1), and the meshes."""
    rows = gt_rows(small_fixture, {o: "rot_5deg" for o in small_fixture.models}, seed=2)
    gt = collect_ground_truth(small_dataset, False)
    targets = resolve_targets(small_dataset.bop19_targets(), gt, small_dataset.target_obj_ids, None)
    pairs = _pairs(select_top_n(rows, targets.targets, -1), gt)
    models = small_dataset.eval_models or small_dataset.models
    return pairs, models, MeshCache(models)


def _jobs(pairs) -> list[RenderJob]:
    """One job per object: its estimated poses, each with its image's intrinsics."""
    out = []
    for obj_id in sorted(set(pairs.obj_id.tolist())):
        rows = np.flatnonzero(pairs.obj_id == obj_id)
        K = np.stack([pairs.images[i].K for i in pairs.image[rows]])
        image = pairs.images[int(pairs.image[rows[0]])]
        out.append(RenderJob(obj_id, pairs.T_est[rows], K, image.height, image.width))
    return out


def _assert_same_crops(got: dict, expected: dict) -> None:
    assert sorted(got) == sorted(expected)
    for j, crops in expected.items():
        assert len(got[j]) == len(crops)
        np.testing.assert_array_equal(got[j].origin, crops.origin)
        for a, b in zip(got[j].depth, crops.depth, strict=True):
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("ahead", [16, 1])
def test_threads_and_the_render_process_give_the_crops_of_render_job(scene_pairs, monkeypatch, ahead) -> None:
    monkeypatch.setattr(render_process, "AHEAD", ahead)  # 1: every reply waits for the caller (back-pressure)
    pairs, _, meshes = scene_pairs
    jobs = _jobs(pairs)
    expected = {j: render_job(job, meshes) for j, job in enumerate(jobs)}
    with ThreadPoolExecutor(2) as pool:
        threaded = dict(ThreadRenderer(pool).render(jobs, meshes))
    with RenderProcess.start() as process:
        forked = dict(process.render(jobs, meshes))
        again = dict(process.render(jobs[:1], meshes))  # one child serves several calls
        assert process.describe() == "a spawned render process"  # torch is imported here (see the docstring)
    _assert_same_crops(threaded, expected)
    _assert_same_crops(forked, expected)
    _assert_same_crops(again, {0: expected[0]})
    with pytest.raises(RuntimeError, match="closed"):
        next(process.render(jobs, meshes))


@dataclass
class _BrokenInTheChild(MeshCache):
    """Object 2's triangles, as sent to the render process, index a vertex that does not exist: the child's
    render raises; this process renders with the intact :class:`RenderMesh`, prepared before they broke."""

    def __post_init__(self) -> None:
        self.many(sorted(self.models))

    def arrays(self, obj_id: int) -> MeshArrays:
        intact = super().arrays(obj_id)
        if obj_id != 2 or obj_id not in self._meshes:
            return intact
        return MeshArrays(intact.vertices, np.full_like(intact.faces, len(intact.vertices) + 7))


@pytest.mark.parametrize("stop", ["killed", "raises"])
def test_a_stopped_render_process_is_replaced_by_this_process(scene_pairs, stop) -> None:
    pairs, models, meshes = scene_pairs
    jobs = _jobs(pairs)
    assert 2 in {job.obj_id for job in jobs}
    expected = {j: render_job(job, meshes) for j, job in enumerate(jobs)}
    given = _BrokenInTheChild(models) if stop == "raises" else meshes
    reason = "IndexError" if stop == "raises" else "exit code -9"
    with RenderProcess.start() as process:
        if stop == "killed":  # as if killed (out of memory): no reply, the pipe closes
            os.kill(process._process.pid, signal.SIGKILL)
            process._process.join()
        with pytest.warns(RuntimeWarning, match=f"render process stopped \\((?s:.*){reason}"):
            got = dict(process.render(jobs, given))
        assert f"{len(jobs)} of {len(jobs)} jobs rendered here" in process.describe()  # the child prepares meshes first
    _assert_same_crops(got, expected)


class _CountingPool(ThreadPoolExecutor):
    """Counts jobs submitted, so that a test can see how far renders run ahead of their caller."""

    submitted = 0

    def submit(self, *args, **kwargs):
        self.submitted += 1
        return super().submit(*args, **kwargs)


def test_threads_render_at_most_ahead_jobs_before_the_caller_takes_them(scene_pairs, monkeypatch) -> None:
    monkeypatch.setattr(render_process, "AHEAD", 2)
    pairs, _, meshes = scene_pairs
    jobs = [_jobs(pairs)[0]] * 9
    taken = []
    with _CountingPool(2) as pool:
        for index, _crops in ThreadRenderer(pool).render(jobs, meshes):
            assert pool.submitted - len(taken) <= 2
            taken.append(index)
    assert sorted(taken) == list(range(9))


def test_a_render_process_left_mid_way_is_closed_not_reused(scene_pairs) -> None:
    pairs, _, meshes = scene_pairs
    jobs = _jobs(pairs) * 3
    process = RenderProcess.start()
    results = process.render(jobs, meshes)
    next(results)
    results.close()  # the caller gave up (an error downstream): the child's other replies must not leak out
    assert process._process.exitcode is not None
    with pytest.raises(RuntimeError, match="closed"):
        next(process.render(jobs, meshes))


def test_closing_an_unused_render_process_stops_it_at_once() -> None:
    process = RenderProcess.start()
    process.close()
    process.close()  # idempotent
    assert process._process.exitcode is not None


def test_the_render_process_is_used_only_where_it_shortens_a_cold_start() -> None:
    assert not render_process.render_process_useful()  # torch is imported in this test process: nothing to overlap
    code = "from bop_cender.eval.render_process import render_process_useful as u; import sys; print(u(), 'torch' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert done.stdout.split() == ["True", "False"]  # and importing the module does not import torch


def test_render_plan_covers_every_pair_once_with_its_poses(scene_pairs) -> None:
    pairs, _, _ = scene_pairs
    rows = np.arange(len(pairs))
    for chunk_poses in (1, 7, 10_000):
        plan = plan_renders(pairs, rows, chunk_poses)
        images = [i for chunk in plan.chunk_images for i in chunk]
        assert len(images) == len(set(images)) == len(set(pairs.image.tolist()))
        assert sorted(p for chunk in plan.chunk_images for m in chunk.values() for p in m) == rows.tolist()
        assert sorted(plan.slots) == rows.tolist()
        for p, ((je, ke), (jg, kg)) in plan.slots.items():
            image = pairs.images[int(pairs.image[p])]
            for j, k, T in ((je, ke, pairs.T_est[p]), (jg, kg, pairs.T_gt[p])):
                job = plan.jobs[j]
                assert job.obj_id == pairs.obj_id[p] and (job.height, job.width) == (image.height, image.width)
                np.testing.assert_array_equal(job.T_cam_model[k], T)
                np.testing.assert_array_equal(job.K[k], image.K)
            chunk = plan.job_chunk[je]
            assert plan.job_chunk[jg] == chunk and int(pairs.image[p]) in plan.chunk_images[chunk]
        for job in plan.jobs:  # each pose once per job
            assert len({T.tobytes() for T in job.T_cam_model}) == len(job)
    assert len(plan_renders(pairs, rows, 1).chunk_images) == len(set(pairs.image.tolist()))
    assert len(plan_renders(pairs, rows, 10_000).chunk_images) == 1


def test_pair_vsd_equals_full_frame_vsd_whoever_renders(scene_pairs, monkeypatch) -> None:
    pairs, models, meshes = scene_pairs
    expected = np.ones((len(pairs), len(VSD_TAUS)))
    for p in range(len(pairs)):
        image = pairs.images[int(pairs.image[p])]
        mesh = meshes(int(pairs.obj_id[p]))
        T = np.stack([pairs.T_est[p], pairs.T_gt[p]])[:, None]
        d_est, d_gt = (
            render_objects_separately([mesh], T, np.stack([image.K] * 2), image.height, image.width).depth[:, 0].numpy()
        )
        test = load_depth(image.depth_path, image.depth_scale)
        expected[p] = vsd(test, d_est, d_gt, image.K, 15.0, VSD_TAUS, models[int(pairs.obj_id[p])].diameter)
    assert 0 < expected.mean() < 1
    monkeypatch.setattr("bop_cender.eval.pair_vsd.CHUNK_POSES", 5)  # several chunks, VSD scored as each arrives
    with ThreadPoolExecutor(2) as pool:
        threaded = pair_vsd(pairs, models, meshes, 15.0, VSD_TAUS, ThreadRenderer(pool), progress=False)
    with RenderProcess.start() as process:
        forked = pair_vsd(pairs, models, meshes, 15.0, VSD_TAUS, process, progress=False)
    np.testing.assert_array_equal(threaded, expected)
    np.testing.assert_array_equal(forked, expected)


def test_a_cold_start_score_renders_in_a_process_with_the_same_numbers(small_fixture, results_dir) -> None:
    csv_path = results_dir / "cold_tless-test.csv"
    write_bop_results(csv_path, gt_rows(small_fixture, {o: "rot_5deg" for o in small_fixture.models}, seed=4))
    cold, warm = results_dir / "cold", results_dir / "warm"
    cmd = [sys.executable, "-m", "bop_cender.cli", "score", str(csv_path), "--data-root", str(small_fixture.root),
           "--no-progress", "--out", str(cold)]  # fmt: skip
    env = {**os.environ, "BOP_CENDER_ALLOCATOR": "system"}
    subprocess.run(cmd, capture_output=True, text=True, check=True, cwd=ROOT, env=env)
    here = score_file(csv_path, data_root=small_fixture.root, out_dir=warm, progress=False, render_process=False)
    assert here.report.metadata.vsd_renders == "threads of the scoring process"
    forked = json.loads((cold / "scores_cold_tless-test.json").read_text())
    threaded = json.loads((warm / "scores_cold_tless-test.json").read_text())
    assert forked["metadata"]["vsd_renders"] == "a forked render process"
    for key in ("AR", "AR_VSD", "AR_MSSD", "AR_MSPD", "AR_MSPD<5px", "AR_MSSD<5%"):
        assert forked[key] == threaded[key]
    assert 0 < forked["AR_VSD"] < 1
    assert (cold / "errors_cold_tless-test.csv").read_text() == (warm / "errors_cold_tless-test.csv").read_text()


def test_a_cold_start_score_that_fails_stops_its_render_process_and_says_why_in_one_line(
    small_fixture, results_dir
) -> None:
    csv_path = results_dir / "bad_tless-test.csv"
    rows = gt_rows(small_fixture)[:2]
    write_bop_results(csv_path, [row(999, r.im_id, r.obj_id, r.score, r.T_cam_model) for r in rows])
    cmd = [sys.executable, "-m", "bop_cender.cli", "score", str(csv_path), "--data-root", str(small_fixture.root),
           "--no-progress"]  # fmt: skip
    env = {**os.environ, "BOP_CENDER_ALLOCATOR": "system"}
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env, timeout=120)
    assert done.returncode == 2
    assert "scene_id: no scene 999" in done.stderr and "Traceback" not in done.stderr
    assert not list(results_dir.glob("scores_*")) and not list(results_dir.glob("errors_*"))
