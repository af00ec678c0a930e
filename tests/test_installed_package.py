"""An installed (not editable) package works: it reads its data through importlib.resources, never the repository.

Builds a wheel of this checkout, installs it into a fresh virtual environment (the dependencies come from the
running interpreter's site-packages, through a ``.pth`` line, so nothing is downloaded) and runs
``bop-cender compare --reference paper`` on a sample scores JSON from a folder outside the checkout.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import venv
from pathlib import Path

import numpy

ROOT = Path(__file__).resolve().parents[1]


def test_the_packaged_paper_table_is_the_committed_one() -> None:
    from bop_cender.report.tables import PAPER_TABLES

    assert PAPER_TABLES.read_text() == (ROOT / "results" / "reference" / "paper_tables.csv").read_text()


def test_a_wheel_installed_in_a_fresh_venv_compares_with_the_paper(tmp_path: Path) -> None:
    src = tmp_path / "src"  # a copy: building in the checkout would leave an egg-info that pip takes for an install
    for name in ("bop_cender", "bop_toolkit_adapters"):
        shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src / name)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "BOP_CENDER_ALLOCATOR")}
    env["BOP_CENDER_ALLOCATOR"] = "system"
    wheels = tmp_path / "wheels"
    build = [
        sys.executable,
        "-m",
        "pip",
        "wheel",
        "--no-deps",
        "--no-build-isolation",
        "-q",
        "-w",
        str(wheels),
        str(src),
    ]
    subprocess.run(build, check=True, cwd=tmp_path, capture_output=True, env=env)
    (wheel,) = wheels.glob("bop_cender-*.whl")

    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    python = env_dir / "bin" / "python"
    site = Path(subprocess.check_output([python, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                                        text=True).strip())  # fmt: skip
    install = [
        sys.executable,
        "-m",
        "pip",
        "--python",
        str(python),
        "install",
        "--no-deps",
        "--no-index",
        "-q",
        str(wheel),
    ]
    subprocess.run(install, check=True, capture_output=True, env=env)
    # The dependencies (numpy, torch, ...) of the running interpreter, as a plain path: its .pth files (an editable
    # install of this checkout among them) are not run, so bop_cender can only come from the wheel. Added after the
    # install, so that pip does not see (and keep, or touch) that editable install.
    (site / "deps.pth").write_text(str(Path(numpy.__file__).resolve().parents[1]) + "\n")

    sample = tmp_path / "sample"
    sample.mkdir()
    scores = {"AR": None, "AR_VSD": None, "AR_MSSD": 0.5, "AR_MSPD": 0.6, "AR_MSPD<5px": 0.7, "AR_MSSD<5%": 0.4,
              "metadata": {"method": "sample", "dataset": "dimo", "split": "sim"}}  # fmt: skip
    (sample / "scores_sample_dimo-sim.json").write_text(json.dumps(scores))
    where = subprocess.run([python, "-c", "import bop_cender; print(bop_cender.__file__)"], env=env, cwd=sample,
                           check=True, capture_output=True, text=True).stdout  # fmt: skip
    assert Path(where.strip()).is_relative_to(site), where
    done = subprocess.run([env_dir / "bin" / "bop-cender", "compare", "scores_sample_dimo-sim.json", "--reference",
                           "paper", "--out", "tables"], env=env, cwd=sample, capture_output=True, text=True)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "CenDerNet [reported]" in done.stdout and "sample" in done.stdout
    assert (sample / "tables" / "comparison_dimo-sim.md").is_file()
