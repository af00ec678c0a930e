"""Fixed meshes that benchmarks and tests share, so their figures refer to one geometry.

``reference_bracket`` is the L-bracket of the renderer study (docs/performance.md) (80 x 50 x 56 mm, 6 mm
plates, four 10 mm holes; 684 faces with 40 segments per hole), the part the renderer's speed
target is stated for.
"""

from __future__ import annotations

import numpy as np
import trimesh


def reference_bracket(sections: int = 40) -> trimesh.Trimesh:
    """The reference L-bracket (manifold3d booleans), centred at its centroid.

    Args:
        sections: segments per hole (40 gives the study's 684 faces; tests use fewer).
    """
    base = trimesh.creation.box((80, 50, 6))
    base.apply_translation((0, 0, 3))
    upright = trimesh.creation.box((80, 6, 56))
    upright.apply_translation((0, 22, 28))
    body = trimesh.boolean.union([base, upright], engine="manifold")
    holes = []
    for x in (-25, 25):
        down = trimesh.creation.cylinder(radius=5, height=20, sections=sections)
        down.apply_translation((x, -8, 3))
        side = trimesh.creation.cylinder(radius=5, height=20, sections=sections)
        side.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))
        side.apply_translation((x, 22, 35))
        holes += [down, side]
    mesh = trimesh.boolean.difference([body, *holes], engine="manifold")
    mesh.apply_translation(-mesh.centroid)
    return mesh
