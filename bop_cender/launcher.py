"""Start ``bop-cender`` with tcmalloc as the allocator where it is installed.

Why: on CPU the batched renderer allocates and frees large temporaries on every call; with glibc
malloc they are mmapped and unmapped each time and about 40 % of the time goes to page faults
(docs/performance.md). Preloading tcmalloc (Debian ``libtcmalloc-minimal4``) keeps them
mapped. The launcher re-executes the command once with ``LD_PRELOAD`` set; it does nothing when
the library is absent, when tcmalloc is already loaded, or when ``BOP_CENDER_ALLOCATOR=system``.
"""

from __future__ import annotations

import glob
import os
import sys

ALLOCATOR_ENV = "BOP_CENDER_ALLOCATOR"
_REEXEC_ENV = "BOP_CENDER_REEXEC"
_PATTERNS = (
    "/usr/lib/*-linux-gnu/libtcmalloc_minimal.so.4",
    "/usr/lib64/libtcmalloc_minimal.so.4",
    "/usr/lib/libtcmalloc_minimal.so.4",
    "/usr/local/lib/libtcmalloc_minimal.so.4",
)


def find_tcmalloc() -> str | None:
    """Path of ``libtcmalloc_minimal.so.4`` if installed, else None."""
    for pattern in _PATTERNS:
        hits = sorted(glob.glob(pattern))
        if hits:
            return hits[0]
    return None


def tcmalloc_active() -> bool:
    """Whether this process runs with tcmalloc preloaded."""
    return "tcmalloc" in os.environ.get("LD_PRELOAD", "")


def reexec_with_tcmalloc(argv: list[str]) -> None:
    """Replace this process by ``python -m bop_cender.cli ARGV`` with tcmalloc preloaded, if useful.

    Returns (doing nothing) when tcmalloc is unavailable, already active, disabled, or this is
    already the re-executed process; otherwise does not return.
    """
    if os.environ.get(ALLOCATOR_ENV, "tcmalloc") == "system" or os.environ.get(_REEXEC_ENV) or tcmalloc_active():
        return
    lib = find_tcmalloc()
    if lib is None:
        return
    env = dict(os.environ)
    env["LD_PRELOAD"] = f"{lib} {env.get('LD_PRELOAD', '')}".strip()
    env[_REEXEC_ENV] = "1"
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(sys.executable, [sys.executable, "-m", "bop_cender.cli", *argv], env)
