"""Benchmark: seconds and peak memory to score a T-LESS-layout results file of 50,000 estimates with the BOP'24/'25
detection protocol (``bop-cender score --protocol bop24``), cold start; optionally the official toolkit's time on the
same file.

Usage:
    python scripts/bench_score_bop24.py [--estimates 50000] [--repeats 1] [--threads 2] [--work DIR]
        [--toolkit DIR [--toolkit-estimates N]] [--out FILE]

What is measured: the wall time and peak resident memory of ``bop-cender score RESULTS.csv --protocol bop24`` in a
fresh Python process (imports, dataset loading, the per-image cap, MSSD and MSPD of every (estimate, GT of its
object) pair, matching at 30 thresholds, APs, writing the scores JSON and detections CSV), limited to ``--threads``
CPU threads. The data: the regression fixture at T-LESS size (720x540) with T-LESS-like meshes (1,000-3,000
vertices; cylinders with a continuous symmetry and a half-turn, 630 symmetry transforms; boxes with 3 half-turns;
asymmetric wedges), 10 scenes x 100 images of 7 instances, and ``--estimates`` rows, 1-4 degrees and 1-6 mm from a
GT instance (no early-out skips work), 50 per image (below the cap of 100, so every row is scored).

``--toolkit DIR``: the toolkit's own ``eval_bop24_pose.py`` (through :mod:`bop_toolkit_adapters.bop24`, CPU, one
worker) on the first ``--toolkit-estimates`` images' rows, and its time per estimate scaled to ``--estimates``
(its cost is per (estimate, GT) pair, a Python loop; a full run of 50,000 takes hours on 2 cores). The figures
are written, with the machine, to ``results/bench/score_bop24_<machine>.md``.
"""

from __future__ import annotations

import argparse
import os
import pickle
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import bench_machine

ROOT = Path(__file__).resolve().parents[1]
#: 10 scenes x 100 images of 7 instances as T-LESS mixes them (see scripts/bench_score.py's BENCH_SPEC_ARGS).
SPEC_ARGS = dict(seed=11, n_scenes=10, n_images=100, objects=(1, 2, 3, 4, 5, 6, 1), min_vertices=1000,
                 target_fraction=1.0, dropout=0.0)  # fmt: skip
PER_IMAGE = 50


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--estimates", type=int, default=50_000)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--threads", type=int, default=2, help="CPU threads the scorer may use (default 2)")
    parser.add_argument("--work", type=Path, default=None, help="work folder, kept between runs (default: temporary)")
    parser.add_argument("--toolkit", type=Path, default=None, help="a checkout of thodan/bop_toolkit, timed too")
    parser.add_argument("--toolkit-estimates", type=int, default=2_000, help="rows the toolkit is timed on")
    parser.add_argument(
        "--out", type=Path, default=None, help="report (default results/bench/score_bop24_<machine>.md)"
    )
    args = parser.parse_args(argv)
    if args.estimates < 1 or args.repeats < 1 or args.threads < 1 or args.toolkit_estimates < 1:
        parser.error("--estimates, --repeats, --threads and --toolkit-estimates must be >= 1")
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        csv = _bench_file(work, args.estimates, "bench")
        env = {**os.environ, **{k: str(args.threads) for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS",
                                                                 "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS")}}  # fmt: skip
        cmd = [sys.executable, "-m", "bop_cender.cli", "score", str(csv), "--data-root", str(work / "tless"),
               "--protocol", "bop24", "--no-progress", "--out", str(work / "out")]  # fmt: skip
        runs = []
        for _ in range(args.repeats):
            runs.append(_timed(cmd, env))
        toolkit = None
        if args.toolkit is not None:
            small = _bench_file(work, args.toolkit_estimates, "benchsmall")
            toolkit = _time_toolkit(small, work, args.toolkit)
    lines = _report(args, runs, toolkit)
    out = args.out or ROOT / "results" / "bench" / f"score_bop24_{bench_machine.machine_slug()}.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"wrote {out}")
    return 0


def _bench_file(work: Path, n: int, name: str) -> Path:
    """The fixture (built once in ``work``) and a results file of ``n`` rows, 50 per image, in image order."""
    from bop_cender.results.bop_csv import write_bop_results
    from bop_cender.synth.regression_fixture import FixtureSpec, bench_estimates, build_fixture

    spec = FixtureSpec(**SPEC_ARGS)
    cached = work / "fixture.pickle"  # the fixture's ground truth, so a rerun in the same --work skips the build
    if cached.is_file():
        built = pickle.loads(cached.read_bytes())
    else:
        built = build_fixture(work / "tless", spec)
        cached.write_bytes(pickle.dumps(built))
    per_instance = 25  # 7 instances, some hidden: 50 rows for nearly every image
    rows = bench_estimates(built, per_instance=per_instance)
    by_image: dict[tuple[int, int], list] = {}
    for r in rows:  # bench_estimates gives each instance's estimates together: taken in turn, instance by instance
        by_image.setdefault((r.scene_id, r.im_id), []).append(r)
    picked = [r for image in by_image.values() for r in _in_turn(image, per_instance)[:PER_IMAGE]][:n]
    if len(picked) < n:
        raise SystemExit(f"the bench fixture gives only {len(picked)} estimates")
    csv = work / f"{name}_tless-test.csv"
    write_bop_results(csv, picked, sort=False)
    return csv


def _in_turn(rows: list, per_instance: int) -> list:
    """An image's rows, ``per_instance`` per instance in a row, reordered to one of each instance in turn."""
    return [rows[k] for j in range(per_instance) for k in range(j, len(rows), per_instance)]


def _timed(cmd: list[str], env: dict) -> dict:
    """Wall time and peak resident memory (MB) of ``cmd`` (the largest child so far: the runs are alike)."""
    start = time.perf_counter()
    done = subprocess.run(cmd, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{done.stderr[-3000:]}")
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024  # kB on Linux
    return {"seconds": seconds, "peak_mb": f"{peak:.0f}", "stdout": done.stdout}


def _time_toolkit(csv: Path, work: Path, toolkit: Path) -> dict:
    """The toolkit's eval_bop24_pose.py on ``csv`` (CPU, one worker), timed in this process."""
    sys.path.insert(0, str(ROOT))
    from bop_cender.data.registry import DatasetRequest, open_dataset
    from bop_cender.results.bop_csv import read_bop_results
    from bop_toolkit_adapters.bop24 import evaluate_bop24, export_bop24
    from bop_toolkit_adapters.runtime import import_toolkit

    _, scripts = import_toolkit(toolkit)
    ds = open_dataset(DatasetRequest("tless", work / "tless", "test"))
    export = export_bop24(ds, csv, work / "toolkit_input", progress=False)
    start = time.perf_counter()
    scores = evaluate_bop24(export, scripts)["scores"]
    return {"seconds": time.perf_counter() - start, "rows": len(read_bop_results(csv)), "scores": scores}


def _report(args, runs: list[dict], toolkit: dict | None) -> list[str]:
    best = min(r["seconds"] for r in runs)
    lines = [
        f"# BOP'24 detection scoring: {args.estimates:,} estimates (T-LESS layout)",
        "",
        f"Machine: {bench_machine.cpu_model()}, {bench_machine.usable_cores()} cores usable; {args.threads} threads; Python {sys.version.split()[0]}.",
        f"Command: `python scripts/bench_score_bop24.py --estimates {args.estimates} --threads {args.threads}"
        + (" --toolkit DIR" if toolkit else "")
        + "`",  # fmt: skip
        "",
        "| what | seconds | peak memory (MB) |",
        "|---|---:|---:|",
    ]
    lines += [f"| bop-cender score --protocol bop24, run {i + 1} | {r['seconds']:.1f} | {r['peak_mb']} |"
              for i, r in enumerate(runs)]  # fmt: skip
    if toolkit:
        scaled = toolkit["seconds"] / toolkit["rows"] * args.estimates
        lines.append(
            f"| toolkit eval_bop24_pose.py (CPU, 1 worker), {toolkit['rows']:,} estimates | {toolkit['seconds']:.1f} | |"
        )
        lines.append(f"| toolkit, scaled to {args.estimates:,} estimates | {scaled:.0f} | |")
    lines += ["", f"Goal: at most 60 s for 50,000 estimates on 2 cores; best run {best:.1f} s.", "", "```",
              runs[-1]["stdout"].strip(), "```"]  # fmt: skip
    return lines


if __name__ == "__main__":
    sys.exit(main())
