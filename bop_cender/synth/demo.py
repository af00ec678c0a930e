"""The embedded default dataset: a small synthetic DIMO or T-LESS dataset generated once, cached.

``--dataset dimo`` or ``--dataset tless`` with no ``--data-root`` uses it (resolved by
:func:`bop_cender.datasets.resolve_data_root`, one level above the data layer and this generator). It is
generated with a fixed seed into ``$BOP_CENDER_CACHE`` (default: the user cache dir,
``~/.cache/bop-cender``), under a folder named by the generator version, so a change of the generator
regenerates it. Generation is atomic: it writes into a temporary sibling folder and renames it when
complete, so an interrupted generation never leaves a half demo that later runs would trust.

The demo's specification, small but a real test of every split: DIMO: 4 scene numbers; three have carrier
2 and compositions 1, 2, 4 (the paper's selection), the fourth has carrier 1 and a mixed composition so
that the selection visibly drops it; all 13 viewpoints (the paper keeps 7); sim variants 00 (split
``sim``), 03 (random light, real poses), 17 and 40 (random poses: split ``train``). T-LESS: 2 test scenes
of 8 views and one PBR scene, each pile a few of the layout's 30 objects. Both use their layout's one
object catalogue.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from pathlib import Path

from bop_cender.errors import ConfigError
from bop_cender.synth.record import GENERATOR_VERSION

#: The generator's version names the demo's cache folder: a change of the generator regenerates it.
DEMO_VERSION = GENERATOR_VERSION
DEMO_SEED = 20221023

CACHE_ENV = "BOP_CENDER_CACHE"


def cache_dir() -> Path:
    """Root of bop-cender's cache: ``$BOP_CENDER_CACHE``, else ``$XDG_CACHE_HOME/bop-cender``, else ``~/.cache/bop-cender``."""
    env = os.environ.get(CACHE_ENV)
    xdg = os.environ.get("XDG_CACHE_HOME")
    if env:
        path, source = Path(env).expanduser(), f"${CACHE_ENV}"
    else:
        path = (Path(xdg).expanduser() if xdg else Path.home() / ".cache") / "bop-cender"
        source = "$XDG_CACHE_HOME" if xdg else "~/.cache"
    for above in (path, *path.parents):  # a file on the way: said with the variable that put it there
        if above.exists():
            if not above.is_dir():
                raise ConfigError(f"is a file, not a folder: bop-cender's cache is {path}", file=above, field=source)
            break
    return path


def demo_root(layout: str) -> Path:
    """Where the demo of ``layout`` (``dimo`` or ``tless``) lives once generated."""
    return cache_dir() / f"demo-{layout}-{DEMO_VERSION}"


def ensure_demo(layout: str, progress: bool = True, announce: Callable[[str], None] | None = None) -> Path:
    """Return the demo dataset's root, generating it first if it is not in the cache.

    Args:
        layout: ``dimo`` or ``tless``.
        progress: show a progress bar on stderr while generating.
        announce: called with one line before a generation starts (the caller decides where it goes).
    """
    root = demo_root(layout)
    if (root / ".complete").is_file():
        return root
    if announce is not None:
        announce(f"generating the {layout} demo dataset (once) into {root}")
    tmp = root.with_name(root.name + ".partial")
    if tmp.exists():
        shutil.rmtree(tmp)
    generate_demo(layout, tmp, seed=DEMO_SEED, progress=progress)
    (tmp / ".complete").write_text(f"{DEMO_VERSION} seed {DEMO_SEED}\n")
    if root.exists():
        shutil.rmtree(root)
    os.replace(tmp, root)
    return root


def demo_spec(layout: str, seed: int):
    """The demo's spec for ``layout`` (``dimo`` or ``tless``)."""
    from bop_cender.synth.write_dimo import DimoSpec
    from bop_cender.synth.write_tless import TlessSpec

    if layout == "dimo":
        return DimoSpec(
            n_scenes=4, variants=(0, 3, 17, 40), carriers=(2, 2, 2, 1), compositions=(1, 2, 4, 3), seed=seed
        )
    if layout == "tless":
        return TlessSpec(n_scenes=2, n_views=8, pbr_scenes=1, pbr_images=4, seed=seed)
    raise ValueError(f"no demo for layout {layout!r}")


def generate_demo(layout: str, root: Path, seed: int, progress: bool = True) -> None:
    """Generate the demo of ``layout`` into ``root`` (both CPU cores)."""
    from bop_cender.synth.generate import generate

    generate(layout, root, demo_spec(layout, seed), workers=2, progress=progress)
