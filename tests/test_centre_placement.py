"""``scripts/centre_placement.py``: per GT part, the nearest 3D centre and whether stage 3 placed it, as a table."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parents[1] / "scripts"))
import centre_placement  # noqa: E402

from bop_cender.centers import Center3D  # noqa: E402


def test_each_part_gets_its_nearest_centre_that_may_be_its_and_its_nearest_placed_object_of_its_id() -> None:
    gt = np.array([[0.0, 0, 0], [100, 0, 0], [0, 100, 0]])
    centres = [Center3D(np.array([3.0, 4, 0]), np.ones(2)), Center3D(np.array([100, 0, 12.0]), np.ones(2), 1, 1)]
    placed = np.array([[1.0, 0, 0], [100, 2, 0], [0, 100, 0]])
    parts = centre_placement.part_placements(gt, [1, 1, 2], centres, placed, [1, 2, 1])
    assert [p.obj_id for p in parts] == [1, 1, 2]
    assert [p.centre_mm for p in parts] == [5.0, 12.0, math.dist((3, 4, 0), (0, 100, 0))]
    # the object at (100, 2, 0) is of id 2: the second part (id 1) is 99 mm from its nearest id-1 placement, (1, 0, 0)
    assert (
        parts[0].placed_mm == 1.0
        and parts[1].placed_mm == 99.0
        and parts[2].placed_mm == math.dist((100, 2, 0), (0, 100, 0))
    )
    # a centre of another id's channel (T-LESS) is not the part's
    other = [Center3D(np.array([0.0, 0, 1]), np.ones(2), 4, 7), Center3D(np.array([0.0, 0, 9]), np.ones(2), 0, 1)]
    (seen,) = centre_placement.part_placements(gt[:1], [1], other, placed, [1, 2, 1])
    assert seen.centre_mm == 9.0 and seen.any_centre_mm == 1.0
    none = centre_placement.part_placements(gt[:1], [3], [], np.zeros((0, 3)), [])
    assert none[0].centre_mm == none[0].placed_mm == none[0].any_centre_mm == math.inf


def test_the_table_bins_parts_by_the_centres_distance_and_counts_the_placed_ones() -> None:
    P = centre_placement.PartPlacement
    parts = [
        P(1, 0.5, 0.2, 0.5),
        P(1, 4.9, 5.0, 4.9),
        P(3, 5.0, 1.0, 5.0),
        P(3, 12.0, 30.0, 2.0),  # seen, in another id's channel
        P(3, math.inf, math.inf, math.inf),
        P(6, 25.0, 2.9, 25.0),
    ]
    lines = centre_placement.placement_table(parts, placed_mm=3.0)
    rows = {line.split("|")[1].strip(): line for line in lines if line.startswith("| ")}
    assert rows["0-5 mm"] == "| 0-5 mm | 2 | 1 |"
    assert rows["5-10 mm"] == "| 5-10 mm | 1 | 1 |"
    assert rows["10-20 mm"] == "| 10-20 mm | 1 | 0 |"
    assert rows[">= 20 mm or none"] == "| >= 20 mm or none | 2 | 1 |"
    assert rows["all"] == "| all | 6 | 3 |"
    assert rows["any channel's centre < 5 mm"] == "| any channel's centre < 5 mm | 3 | |"
    assert rows["3"] == "| 3 | 3 | 0 | 1 | 1 |" and rows["1"] == "| 1 | 2 | 2 | 2 | 1 |"
    assert rows["6"] == "| 6 | 1 | 0 | 0 | 1 |"


def test_meaningless_flags_are_one_usage_error_before_any_work() -> None:
    script = Path(__file__).parents[1] / "scripts" / "centre_placement.py"
    for flags, message in ((["--scenes", "0"], "--scenes must be at least 1"), (["--placed-mm", "-1"], "--placed-mm")):
        done = subprocess.run([sys.executable, str(script), *flags], capture_output=True, text=True, timeout=120)
        assert done.returncode == 2 and message in done.stderr and "Traceback" not in done.stderr
