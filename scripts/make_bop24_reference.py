"""Write ``tests/eval/fixtures/toolkit_reference_bop24.json``: the official toolkit's BOP'24 figures on the test fixture.

Usage:
    python scripts/make_bop24_reference.py --toolkit DIR [--out FILE]

The tests' small T-LESS-layout fixture (``tests.eval.scoring_data.SMALL``) is built in a temporary folder, and for
each case of :data:`CASES` the rows of :func:`bop_cender.synth.detection_rows.detection_rows` are scored by the
toolkit's own ``scripts/eval_bop24_pose.py`` (``DIR``: a checkout of thodan/bop_toolkit; run through
:mod:`bop_toolkit_adapters.bop24`, nothing of it copied). The JSON keeps, per case, the seven keys and every
per-object AP per threshold; ``tests/eval/test_scoring_bop24.py`` requires ours to equal them to 1e-9.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: name -> detection_rows arguments. ``edge``: ties, duplicates, negative scores, unknown ids, non-target images, a
#: missing scene and an image with 160 rows (its cut among equal scores); ``unknowntime``: one image's time is -1.
CASES = {
    "edge": {"seed": 3, "crowded": 130},
    "unknowntime": {"seed": 4, "unknown_time": True},
    "dense": {"seed": 8, "crowded": 60},
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--toolkit", type=Path, required=True, help="a checkout of thodan/bop_toolkit")
    parser.add_argument(
        "--out", type=Path, default=ROOT / "tests" / "eval" / "fixtures" / "toolkit_reference_bop24.json"
    )
    args = parser.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from bop_cender.data.bop_io import save_json
    from bop_cender.data.registry import DatasetRequest, open_dataset
    from bop_cender.results.bop_csv import write_bop_results
    from bop_cender.synth.detection_rows import detection_rows
    from bop_cender.synth.regression_fixture import build_fixture
    from bop_toolkit_adapters.bop24 import evaluate_bop24, export_bop24
    from bop_toolkit_adapters.runtime import import_toolkit
    from tests.eval.scoring_data import SMALL

    _, scripts = import_toolkit(args.toolkit)
    commit = subprocess.run(["git", "-C", str(args.toolkit), "rev-parse", "HEAD"], capture_output=True, text=True)
    out: dict = {
        "note": "BOP'24 figures of the official toolkit's scripts/eval_bop24_pose.py (thodan/bop_toolkit"
        f" {commit.stdout.strip() or '@ cea62d6'}) on the tests' SMALL fixture and detection_rows(**case);"
        " written by scripts/make_bop24_reference.py --toolkit DIR. No toolkit code is in this repo.",
        "cases": {},
    }
    with tempfile.TemporaryDirectory() as tmp:
        built = build_fixture(Path(tmp) / "tless", SMALL)
        ds = open_dataset(DatasetRequest("tless", built.root, "test"))
        for name, case in CASES.items():
            csv = Path(tmp) / f"{name}_tless-test.csv"
            write_bop_results(csv, detection_rows(built, **case), sort=False)
            toolkit = evaluate_bop24(export_bop24(ds, csv, Path(tmp) / f"export_{name}", progress=False), scripts)
            out["cases"][name] = {
                "args": case,
                "scores": toolkit["scores"],
                "object_aps": {t: {str(o): aps for o, aps in v.items()} for t, v in toolkit["object_aps"].items()},
            }
            print(name, toolkit["scores"])
    save_json(args.out, out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
