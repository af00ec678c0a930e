"""The embedded demo datasets' specification: small, but a real test of every split.

DIMO: 4 scene numbers; three have carrier 2 and compositions 1, 2, 4 (the paper's selection), the
fourth has carrier 1 and a mixed composition so that the selection visibly drops it; all 13
viewpoints (the paper keeps 7); sim variants 00 (split ``sim``), 03 (random light, real poses),
17 and 40 (random poses: split ``train``). T-LESS: 2 test scenes of 8 views and one PBR scene.
"""

from __future__ import annotations

from pathlib import Path

from bop_cender.synth.generate import generate
from bop_cender.synth.write_dimo import DimoSpec
from bop_cender.synth.write_tless import TlessSpec


def demo_spec(layout: str, seed: int):
    """The demo's spec for ``layout`` (``dimo`` or ``tless``)."""
    if layout == "dimo":
        return DimoSpec(
            n_scenes=4, variants=(0, 3, 17, 40), carriers=(2, 2, 2, 1), compositions=(1, 2, 4, 3), seed=seed
        )
    if layout == "tless":
        return TlessSpec(n_scenes=2, n_views=8, pbr_scenes=1, pbr_images=4, seed=seed)
    raise ValueError(f"no demo for layout {layout!r}")


def generate_demo(layout: str, root: Path, seed: int, progress: bool = True) -> None:
    """Generate the demo of ``layout`` into ``root`` (both CPU cores)."""
    generate(layout, root, demo_spec(layout, seed), workers=2, progress=progress)
