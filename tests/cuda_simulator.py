"""Running a CUDA kernel's test in numba's CUDA simulator, for machines without a GPU.

The simulator must be switched on before numba is imported (``NUMBA_ENABLE_CUDASIM=1``), so a kernel's check runs as
a script in a subprocess, every CUDA thread a Python thread, and prints one line starting "ok " per result for the
test to read.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def simulated_ok_lines(source: str, timeout: float = 600, compares_compiled_raster: bool = True) -> list[str]:
    """The "ok ..." lines printed by ``source`` (a script whose ``{tests}`` is replaced by the tests folder, which it
    may put on ``sys.path``) run in numba's CUDA simulator; its failure fails the test with its error output. With
    ``compares_compiled_raster`` (a kernel checked against the CPU's compiled render), skips where those loops cannot
    repeat torch's rounding (nothing to compare the kernel with)."""
    from bop_cender.render.compiled_raster import AVAILABLE

    if compares_compiled_raster and not AVAILABLE:
        pytest.skip("the CPU loops cannot repeat torch's addcmul rounding here: nothing to compare the kernel with")
    script = source.format(tests=str(ROOT / "tests"))
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1", "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, done.stderr[-3000:]
    return [line for line in done.stdout.splitlines() if line.startswith("ok ")]
