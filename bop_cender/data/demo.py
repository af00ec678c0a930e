"""The embedded default dataset: a small synthetic DIMO or T-LESS dataset generated once, cached.

``--dataset dimo`` or ``--dataset tless`` with no ``--data-root`` uses it. It is generated with a
fixed seed into ``$BOP_CENDER_CACHE`` (default: the user cache dir, ``~/.cache/bop-cender``),
under a folder named by the generator version, so a change of the generator regenerates it.
Generation is atomic: it writes into a temporary sibling folder and renames it when complete,
so an interrupted generation never leaves a half demo that later runs would trust.
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

#: Bump when the synthetic generator's output changes, so cached demos are regenerated.
DEMO_VERSION = "v1"
DEMO_SEED = 20221023

CACHE_ENV = "BOP_CENDER_CACHE"


def cache_dir() -> Path:
    """Root of bop-cender's cache: ``$BOP_CENDER_CACHE``, else ``$XDG_CACHE_HOME/bop-cender``, else ``~/.cache/bop-cender``."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / "bop-cender"


def demo_root(layout: str) -> Path:
    """Where the demo of ``layout`` (``dimo`` or ``tless``) lives once generated."""
    return cache_dir() / f"demo-{layout}-{DEMO_VERSION}"


def ensure_demo(layout: str, progress: bool = True) -> Path:
    """Return the demo dataset's root, generating it first if it is not in the cache.

    Args:
        layout: ``dimo`` or ``tless``.
        progress: show a progress bar on stderr while generating.
    """
    from bop_cender.synth.demo_spec import generate_demo

    root = demo_root(layout)
    if (root / ".complete").is_file():
        return root
    print(f"[bop-cender] generating the {layout} demo dataset (once) into {root}", file=sys.stderr)
    tmp = root.with_name(root.name + ".partial")
    if tmp.exists():
        shutil.rmtree(tmp)
    generate_demo(layout, tmp, seed=DEMO_SEED, progress=progress)
    (tmp / ".complete").write_text(f"{DEMO_VERSION} seed {DEMO_SEED}\n")
    if root.exists():
        shutil.rmtree(root)
    os.replace(tmp, root)
    return root
