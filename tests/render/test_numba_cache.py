"""The compiled loops' on-disk cache: one folder per version of their sources, so that no stale code is read.

numba checks only the cached function's own file; the cost kernel inlines the rasteriser of another file, so after
an update of the rasteriser alone its old cache would be read. The folder's name changes with any source of
``bop_cender/render`` and ``bop_cender/pose``.
"""

from __future__ import annotations

from pathlib import Path

import numba
import numpy as np

from bop_cender.render import numba_cache


def _tree(root: Path, text: str) -> None:
    for folder in ("render", "pose"):
        (root / folder).mkdir(parents=True, exist_ok=True)
        (root / folder / "kernel.py").write_text(f"# {folder}\n")
    (root / "render" / "raster.py").write_text(text)


def test_the_fingerprint_follows_every_compiled_source(tmp_path) -> None:
    _tree(tmp_path, "x = 1\n")
    first = numba_cache.source_fingerprint(tmp_path)
    assert len(first) == 16 and first == numba_cache.source_fingerprint(tmp_path)
    (tmp_path / "render" / "raster.py").write_text("x = 2\n")  # the callee alone changes
    assert numba_cache.source_fingerprint(tmp_path) != first
    (tmp_path / "render" / "raster.py").write_text("x = 1\n")
    (tmp_path / "elsewhere.py").write_text("y = 1\n")  # not under render/ or pose/: no compiled code there
    assert numba_cache.source_fingerprint(tmp_path) == first


def test_the_package_folder_is_named_by_the_fingerprint_and_holds_the_cache() -> None:
    folder = numba_cache.cache_folder()
    assert folder is not None and Path(folder).name == f"numba-{numba_cache.source_fingerprint()}"

    def triple(x):
        return 3 * x

    compiled = numba_cache.cached_njit(triple)
    assert compiled(np.int64(2)) == 6
    assert any(Path(folder).rglob("*triple*.nbi"))  # numba's index of the compiled function, in this version's folder
    assert folder != numba.config.CACHE_DIR  # the setting is the caller's again


def test_another_folder_where_the_package_is_not_writable(tmp_path, monkeypatch) -> None:
    blocker = tmp_path / "package"
    blocker.write_text("a file where the package folder would be: nothing can be made under it")
    monkeypatch.setattr(numba_cache, "PACKAGE_ROOT", blocker)
    monkeypatch.setattr(numba_cache, "source_fingerprint", lambda: "0123456789abcdef")
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    folder = numba_cache.cache_folder.__wrapped__()
    assert folder == str(tmp_path / "cache" / "bop-cender" / "numba-0123456789abcdef")
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba"))
    assert numba_cache.cache_folder.__wrapped__() == str(tmp_path / "numba" / "bop-cender" / "numba-0123456789abcdef")
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(blocker))
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker))
    assert numba_cache.cache_folder.__wrapped__() is None  # nothing writable: compiled in each process
    monkeypatch.setattr(numba_cache, "cache_folder", lambda: None)
    assert numba_cache.cached_njit(lambda x: x + 1)(1) == 2


def test_older_versions_folders_of_the_package_are_removed(tmp_path, monkeypatch) -> None:
    (tmp_path / "__pycache__" / "numba-aaaaaaaaaaaaaaaa").mkdir(parents=True)
    (tmp_path / "__pycache__" / "other").mkdir()
    monkeypatch.setattr(numba_cache, "PACKAGE_ROOT", tmp_path)
    monkeypatch.setattr(numba_cache, "source_fingerprint", lambda: "bbbbbbbbbbbbbbbb")
    assert numba_cache.cache_folder.__wrapped__() == str(tmp_path / "__pycache__" / "numba-bbbbbbbbbbbbbbbb")
    assert sorted(p.name for p in (tmp_path / "__pycache__").iterdir()) == ["numba-bbbbbbbbbbbbbbbb", "other"]
