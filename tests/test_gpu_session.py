"""``scripts/gpu_session.sh``: the prepared device calls answer ``--help``, refuse an unknown phase, and (slow) the
training phase runs end to end on the CPU at a tiny size, leaving the run's bundle under ``$OUT``."""

from __future__ import annotations

import os
import subprocess
import sys
import tarfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "gpu_session.sh"


def _run(*args: str, env: dict[str, str] | None = None, timeout: int = 60) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(SCRIPT), *args], capture_output=True, text=True, timeout=timeout, env=env)


def test_help_prints_the_phases_and_an_unknown_phase_is_refused() -> None:
    done = _run("--help")
    assert done.returncode == 0 and "check" in done.stdout and "train" in done.stdout
    assert "set -euo" not in done.stdout  # the header alone
    bad = _run("bench")
    assert bad.returncode == 2 and "usage: bash scripts/gpu_session.sh check|train" in bad.stderr


def test_votes_other_than_0_or_1_are_refused(tmp_path: Path) -> None:
    done = _run("train", env={**os.environ, "OUT": str(tmp_path / "out"), "VOTES": "yes"})
    assert done.returncode == 2 and "VOTES must be 0 or 1, got 'yes'" in done.stderr
    assert not (tmp_path / "out").exists()  # refused before anything is written


def test_cuda_asked_for_without_cuda_is_one_line_and_exit_2(tmp_path: Path) -> None:
    pytest.importorskip("trimesh")
    import torch

    if torch.cuda.is_available():
        pytest.skip("a CUDA device is present")
    env = {**os.environ, "OUT": str(tmp_path / "out"), "DEVICE": "cuda", "PATH": os.path.dirname(sys.executable)
           + os.pathsep + os.environ["PATH"]}  # fmt: skip
    done = _run("check", env=env)
    assert done.returncode == 2
    assert "DEVICE=cuda but torch sees no CUDA device" in done.stdout
    assert "Traceback" not in done.stderr


@pytest.mark.slow
def test_the_training_phase_runs_on_the_cpu_and_bundles_the_run(tmp_path: Path) -> None:
    env = {
        **os.environ,
        "PATH": os.path.dirname(sys.executable) + os.pathsep + os.environ["PATH"],
        "OUT": str(tmp_path / "out"),
        "DEVICE": "cpu",
        "SCENES": "1",
        "VARIANTS": "16",
        "TRAIN_MINUTES": "2",
        "BATCH": "2",
        "WORKERS": "2",
        "DATA": str(tmp_path / "data"),
        "RUN": str(tmp_path / "run"),
        "VOTES": "1",  # the paper's network with centre votes (the path without them is --center-votes' absence)
    }
    done = _run("train", env=env, timeout=600)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    bundle = tmp_path / "out" / "train_run.tar.gz"
    with tarfile.open(bundle) as tar:
        names = tar.getnames()
    assert {"run/weights.pt", "run/checkpoint.pt", "run/metrics.csv"} <= set(names)  # enough to resume elsewhere
    log = (tmp_path / "out" / "session.log").read_text()
    assert "validation_heatmaps" in log and "failed" not in log
    assert "center_f1" in (tmp_path / "out" / "validation_heatmaps.txt").read_text()
    # carried back, the bundle continues the run (RESUME_BUNDLE) in a fresh place
    env2 = {
        **env,
        "RUN": str(tmp_path / "elsewhere" / "run"),
        "RESUME_BUNDLE": str(bundle),
        "OUT": str(tmp_path / "out2"),
    }
    again = _run("train", env=env2, timeout=600)
    assert again.returncode == 0, again.stdout[-3000:] + again.stderr[-3000:]
    assert "Traceback" not in (tmp_path / "out2" / "train.txt").read_text()
    assert "dimo+votes" in (tmp_path / "out" / "train.txt").read_text()
