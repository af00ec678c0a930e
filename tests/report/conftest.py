"""The scoring tests' fixtures (a small rendered T-LESS-layout dataset and its DIMO copy), shared here."""

import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402

from tests.eval.conftest import dimo_copy, results_dir, small_dataset, small_fixture  # noqa: F401  (pytest fixtures)

sys.path.insert(0, str(Path(__file__).parents[1]))
import method_data  # noqa: E402

#: Cheap settings of the method (tests/test_runner.py's): rows of no precision, made in seconds.
CHEAP = method_data.CHEAP


@pytest.fixture(scope="session")
def report_run(tmp_path_factory) -> Path:
    """A run of the method (oracle heatmaps) over a 2-scene DIMO set, with ``--vis`` figures and timings: the CSV.

    The figure of scene 000001 is removed, so that a report shows one figure made by the run and one drawn by it."""
    from bop_cender.method import CenDerNetConfig
    from bop_cender.runner import RunRequest, run

    base = tmp_path_factory.mktemp("report_run")
    root = method_data.build(base / "dimo", n_scenes=2)
    out = base / "run" / "cendernet-oracle_dimo-real.csv"
    config = CenDerNetConfig.for_dataset("dimo").with_settings(CHEAP)
    summary = run(RunRequest(dataset="dimo", data_root=str(root), split="real", out=out, config=config,
                             vis_dir=base / "vis"))  # fmt: skip
    assert summary.scenes == 2 and not summary.failed
    (base / "vis" / "000001.png").unlink()
    return out
