"""Where the compiled loops' machine code is cached on disk: a folder named by a fingerprint of their sources.

Why. numba's on-disk cache checks only the source file of the function it compiled, not the files of the functions
that function calls (numba's documented limitation). Our loops call across files: the cost kernel
(``pose/cost_kernel.py``) and the scene polish's kernel (``pose/window_kernel.py``) inline the rasteriser of
``render/compiled_raster.py``. After an update that changes the rasteriser alone (a ``git pull`` in an editable
install), their cached code would still hold the old rasteriser, silently: other costs than the source says. Here the
cache folder is named by a hash of every source file under ``bop_cender/render`` and ``bop_cender/pose`` (where all
compiled code lives), so any change there compiles everything afresh (about 4 s, once), and nothing stale is read.

The folder: ``bop_cender/__pycache__/numba-<fingerprint>`` where the package is writable (older fingerprints' folders
beside it are removed), else ``$NUMBA_CACHE_DIR/bop-cender/`` or the user's cache folder
(``$XDG_CACHE_HOME`` or ``~/.cache``, then ``bop-cender/``); with none writable, each process compiles its loops.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
from collections.abc import Callable, Iterable
from functools import cache
from pathlib import Path

import numba

PACKAGE_ROOT = Path(__file__).resolve().parents[1]
#: The folders whose sources the compiled loops are built from (every ``numba.njit`` of the package is in them).
COMPILED_SOURCE_FOLDERS = ("render", "pose")


def source_fingerprint(root: Path = PACKAGE_ROOT, folders: Iterable[str] = COMPILED_SOURCE_FOLDERS) -> str:
    """16 hex digits of the SHA-256 of the ``.py`` files under ``root/folder`` (their paths and bytes, in order)."""
    digest = hashlib.sha256()
    for folder in folders:
        for path in sorted((root / folder).rglob("*.py")):
            digest.update(path.relative_to(root).as_posix().encode())
            digest.update(b"\0")
            digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


@cache
def cache_folder() -> str | None:
    """The folder of this package version's compiled code (created), or None where no candidate is writable."""
    name = f"numba-{source_fingerprint()}"
    user_cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "bop-cender"
    numba_cache = os.environ.get("NUMBA_CACHE_DIR")
    candidates = [(PACKAGE_ROOT / "__pycache__", True)]
    candidates += [(Path(numba_cache) / "bop-cender", False)] if numba_cache else []
    candidates += [(user_cache, False)]
    for parent, own in candidates:
        folder = parent / name
        try:
            folder.mkdir(parents=True, exist_ok=True)
            tempfile.TemporaryFile(dir=folder).close()
        except OSError:
            continue
        if own:  # this checkout's folder: older versions' code is never read again
            for old in parent.glob("numba-*"):
                if old.name != name:
                    shutil.rmtree(old, ignore_errors=True)
        return str(folder)
    return None


def cached_njit(py_func: Callable | None = None, **options) -> Callable:
    """``numba.njit(cache=True, **options)`` with its cache in :func:`cache_folder` (``@cached_njit`` or
    ``@cached_njit(nogil=True, ...)``); compiled in each process, uncached, where no folder is writable."""
    if py_func is None:
        return lambda func: cached_njit(func, **options)
    folder = cache_folder()
    if folder is None:
        return numba.njit(**options)(py_func)
    before = numba.config.CACHE_DIR
    numba.config.CACHE_DIR = folder  # numba's locator reads it when the function is decorated, not later
    try:
        return numba.njit(cache=True, **options)(py_func)
    except RuntimeError:  # numba's "cannot cache function ...: no locator available" (the folder went read-only)
        return numba.njit(**options)(py_func)  # compiled afresh in each process (about 4 s)
    finally:
        numba.config.CACHE_DIR = before
