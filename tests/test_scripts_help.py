"""Every script under ``scripts/`` answers ``--help`` (argparse expands ``%`` in help strings: a bare ``5 %``
crashed ``diagnose_poses.py --help`` with a traceback)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"
# Helpers imported by the others, not commands.
NOT_COMMANDS = {"bench_machine.py", "cycles_look.py", "cycles_scene.py"}


@pytest.mark.parametrize("script", sorted(p.name for p in SCRIPTS.glob("*.py") if p.name not in NOT_COMMANDS))
def test_script_help_prints_usage(script: str) -> None:
    done = subprocess.run(
        [sys.executable, str(SCRIPTS / script), "--help"], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "usage:" in done.stdout
    assert "Traceback" not in done.stderr
