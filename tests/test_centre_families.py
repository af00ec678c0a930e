"""scripts/centre_families.py: the per-family lookups of the centres in a class-agnostic map, and a run on the
oracle's maps (every instance found)."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parents[1] / "scripts"))
import centre_families  # noqa: E402

from bop_cender.centers import CenterConfig  # noqa: E402
from bop_cender.cli import main as cli_main  # noqa: E402

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "centre_families.py"


def _blob(H: int, W: int, x: float, y: float, sigma: float = 2.0) -> np.ndarray:
    u = np.arange(W) + 0.5
    v = np.arange(H) + 0.5
    return np.exp(-((u[None] - x) ** 2 + (v[:, None] - y) ** 2) / (2 * sigma**2))


def test_lookups_read_the_map_at_each_centre_and_the_nearest_peak() -> None:
    agnostic = _blob(30, 40, 10.5, 8.5) + 0.5 * _blob(30, 40, 30.5, 20.5)
    centres = np.array([[10.5, 8.5], [33.5, 24.5], [5.5, 25.5], [45.0, 5.0]])  # the last outside the view
    lookups = centre_families.view_lookups(agnostic, centres, ["plate", "bracket", "bracket", "plate"], CenterConfig())
    assert [lk.family for lk in lookups] == ["plate", "bracket", "bracket"]
    assert lookups[0].value == 1.0 and lookups[0].nearest_peak_px == 0.0
    assert math.isclose(lookups[1].nearest_peak_px, math.hypot(3, 4))  # the lower blob's peak, 5 px away
    assert lookups[2].value < 0.01 and math.isclose(lookups[2].nearest_peak_px, math.hypot(5, 17))
    table = centre_families.family_table(lookups, peak_px=5.0)
    assert table[2] == "| bracket | 2 | 0.22 | 0.50 | 5/5/18 |"  # 5 px counts as found; (0.44 + 0) / 2
    assert table[3] == "| plate | 1 | 1.00 | 1.00 | 0/0/0 |"
    none = centre_families.family_table([centre_families.CentreLookup("shaft", 0.0, math.inf)], peak_px=5.0)
    assert none[2] == "| shaft | 1 | 0.00 | 0.00 | none/none/none |"


def test_on_the_oracle_maps_every_instance_is_found_and_named_by_its_family(tmp_path) -> None:
    root = tmp_path / "tless"
    assert cli_main(["synth", "--layout", "tless", "--out", str(root), "--scenes", "1", "--views", "2",
                     "--pbr-scenes", "0", "--seed", "5", "--no-contact-sheets"]) == 0  # fmt: skip
    done = subprocess.run(
        [sys.executable, str(SCRIPT), "--dataset", "tless", "--data-root", str(root), "--weights", "oracle"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    rows = [line for line in done.stdout.splitlines() if line.startswith("| ") and not line.startswith("| family")]
    assert rows, done.stdout
    families = {"shaft", "tube", "flange", "hex_part", "slotted_plate", "bracket"}
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert cells[0] in families and int(cells[1]) > 0
        assert float(cells[2]) > 0.95 and cells[3] == "1.00", row  # the GT's own blobs: a peak on every centre
    bad = subprocess.run([sys.executable, str(SCRIPT), "--peak-px", "0"], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "--peak-px must be above 0" in bad.stderr
