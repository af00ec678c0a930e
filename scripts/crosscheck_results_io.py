"""Cross-check our BOP results CSV I/O against the official BOP toolkit's ``inout``.

Usage:
    python scripts/crosscheck_results_io.py TOOLKIT_DIR [--sample CSV ...]

TOOLKIT_DIR is a checkout/export of ``thodan/bop_toolkit`` (the folder holding ``bop_toolkit_lib``).
Its image-I/O dependencies (``pypng``, ``imageio``) must be importable; put them on PYTHONPATH if
needed. The toolkit is never a dependency of bop-cender: when it cannot be imported this prints why
and exits 0.

Checks, each value compared exactly (float64 bit for bit):
  1. DIMO-style results (suffixed scene ids ``000123_17`` -> 12317) and T-LESS-style results
     written by our writer are read identically by ``inout.load_bop_results`` and by our reader,
     and pass ``inout.check_consistent_timings``.
  2. A file written by ``inout.save_bop_results`` reads back identically with our reader.
  3. The real sample submission(s) read identically with both.
  4. A file with inconsistent per-image times fails both checks.
  5. ``parse_result_filename`` agrees on every file name used.
Exits 1 on any mismatch.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from bop_cender.data.types import CameraView, GtObject, Scene
from bop_cender.errors import ResultsError
from bop_cender.estimates import ObjectEstimate, SceneEstimate
from bop_cender.geometry.poses import make_pose
from bop_cender.results.bop_csv import (
    BopEstimate,
    parse_result_filename,
    read_bop_results,
    scene_estimates_to_rows,
    write_bop_results,
)
from bop_toolkit_adapters.runtime import ToolkitUnavailable, import_toolkit

DEFAULT_SAMPLES = Path(__file__).resolve().parents[1].parent / "shared/reference/bop_results_samples"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("toolkit_dir", type=Path, help="folder that contains bop_toolkit_lib/")
    parser.add_argument("--sample", type=Path, nargs="*", help="real BOP results CSVs (default: shared samples)")
    args = parser.parse_args(argv)

    try:
        import_toolkit(args.toolkit_dir)
    except ToolkitUnavailable as e:
        print(f"cross-check not run: {e}", file=sys.stderr)
        return 2
    from bop_toolkit_lib import inout

    print(f"official toolkit: {Path(inout.__file__).resolve()}")

    failures: list[str] = []
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        tmp_dir = Path(tmp)
        dimo = tmp_dir / "cendernet_dimo-sim.csv"
        write_bop_results(dimo, _dimo_rows(rng))
        tless = tmp_dir / "cendernet_tless-test-primesense.csv"
        write_bop_results(tless, _tless_rows(rng))
        for path in (dimo, tless):
            failures += _compare(inout, path, expect_timings_ok=True)
        scene_ids = sorted({r["scene_id"] for r in inout.load_bop_results(str(dimo))})
        _report(
            f"DIMO scene ids 000004_00, 000123_17 read by the toolkit as {scene_ids}",
            scene_ids == [400, 12317],
            failures,
        )

        theirs = tmp_dir / "official_tless-test.csv"
        inout.save_bop_results(str(theirs), [_to_toolkit(r) for r in _tless_rows(rng)])
        failures += _compare(inout, theirs, expect_timings_ok=True)

        rows = _tless_rows(rng)
        bad = tmp_dir / "badtimes_tless-test.csv"
        k = next(i for i, r in enumerate(rows) if r.time >= 0)  # an image with a known time
        rows[k + 1] = BopEstimate(rows[k].scene_id, rows[k].im_id, 5, 0.1, np.eye(3), [0, 0, 700], rows[k].time + 0.01)
        inout.save_bop_results(str(bad), [_to_toolkit(r) for r in rows])  # our writer would refuse this file
        ok, msg, _, _ = inout.check_consistent_timings(inout.load_bop_results(str(bad)), "im_id")
        try:
            read_bop_results(bad)
            ours_ok = True
        except ResultsError:
            ours_ok = False
        _report(f"inconsistent times rejected by both ({msg})", not ok and not ours_ok, failures)

    samples = args.sample if args.sample is not None else sorted(DEFAULT_SAMPLES.glob("*.csv"))
    if not samples:
        print(f"no sample submission found at {DEFAULT_SAMPLES}; real-file check skipped")
    for path in samples:
        failures += _compare(inout, path, expect_timings_ok=True)

    if failures:
        print(f"\nFAILED: {len(failures)} check(s)")
        return 1
    print("\nall checks passed: our reader/writer agree with the official toolkit value for value")
    return 0


def _compare(inout, path: Path, expect_timings_ok: bool) -> list[str]:
    """Read ``path`` with both readers; compare every value exactly; check timings and the file name."""
    failures: list[str] = []
    ours = read_bop_results(path)
    theirs = inout.load_bop_results(str(path), version="bop19")
    same = len(ours) == len(theirs) and all(_equal(a, b) for a, b in zip(ours, theirs, strict=False))
    _report(f"{path.name}: {len(ours)} rows identical in both readers", same, failures)
    ok, msg, _, _ = inout.check_consistent_timings(theirs, "im_id")
    _report(f"{path.name}: toolkit check_consistent_timings -> {msg}", ok == expect_timings_ok, failures)
    name, theirs_name = parse_result_filename(path.name), inout.parse_result_filename(path.name)
    parts = (name.method, name.dataset, name.split, name.split_type)
    _report(f"{path.name}: file name parsed alike {parts}", parts == tuple(theirs_name[1:5]), failures)
    return failures


def _equal(ours: BopEstimate, theirs: dict) -> bool:
    return (
        (ours.scene_id, ours.im_id, ours.obj_id, ours.score, ours.time)
        == (theirs["scene_id"], theirs["im_id"], theirs["obj_id"], theirs["score"], theirs["time"])
        and np.array_equal(ours.R, theirs["R"])
        and np.array_equal(ours.t, theirs["t"].reshape(3))
    )


def _report(what: str, ok: bool, failures: list[str]) -> None:
    print(f"  [{'ok' if ok else 'FAIL'}] {what}")
    if not ok:
        failures.append(what)


def _dimo_rows(rng: np.random.Generator) -> list[BopEstimate]:
    """Rows of two synthetic DIMO scenes (``000123_17``, ``000004_00``): 4 views x 3 objects each."""
    K = np.array([[600.0, 0, 160], [0, 600.0, 128], [0, 0, 1]])
    rows: list[BopEstimate] = []
    for scene_id in ("000123_17", "000004_00"):
        views = tuple(
            CameraView(k, K, make_pose(Rotation.random(random_state=rng).as_matrix(), [0, 0, 700.0]), 320, 256)
            for k in range(0, 8, 2)
        )
        gt = tuple(
            GtObject(int(o), make_pose(Rotation.random(random_state=rng).as_matrix(), rng.normal(0, 80, 3)))
            for o in (1, 3, 6)
        )
        scene = Scene("dimo", "sim", scene_id, views, gt)
        objects = tuple(ObjectEstimate(g.obj_id, g.T_world_model, float(rng.random())) for g in gt)
        rows += scene_estimates_to_rows(scene, SceneEstimate(scene.key, scene_id, objects, float(rng.random() * 9)))
    return rows


def _tless_rows(rng: np.random.Generator) -> list[BopEstimate]:
    """T-LESS-like rows: scenes 1..20, a few objects per image, one time per image (some unknown, -1)."""
    rows: list[BopEstimate] = []
    for scene in (1, 7, 20):
        for im in range(0, 500, 97):
            time = -1.0 if im == 0 else float(rng.random())
            for obj in rng.choice(np.arange(1, 31), 4, replace=False):
                R = Rotation.random(random_state=rng).as_matrix()
                t = rng.normal([0, 0, 750], [60, 60, 80])
                rows.append(BopEstimate(scene, im, int(obj), float(rng.random()), R, t, time))
    return rows


def _to_toolkit(row: BopEstimate) -> dict:
    return {"scene_id": row.scene_id, "im_id": row.im_id, "obj_id": row.obj_id, "score": row.score,
            "R": row.R.copy(), "t": row.t.reshape(3, 1).copy(), "time": row.time}  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
