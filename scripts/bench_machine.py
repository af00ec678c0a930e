"""What the benchmark scripts say about the machine they ran on, and the results file name built from it.

Imported by ``scripts/bench_*.py`` (run as ``python scripts/bench_x.py``, so this folder is on ``sys.path``).
"""

from __future__ import annotations

import os
import platform
import re
from pathlib import Path


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), else what :mod:`platform` knows."""
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        for line in cpuinfo.read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or "cpu"


def usable_cores() -> int:
    """Cores this process may run on (its affinity, which a container or ``taskset`` may narrow)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def machine_slug(gpu: str | None = None) -> str:
    """``amd-epyc-2cores`` (then the GPU's name, where one is given): the results file's name."""
    name = f"{cpu_model()}-{usable_cores()}cores" + (f"-{gpu}" if gpu else "")
    return re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-")
