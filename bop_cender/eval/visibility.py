"""Visible fractions of GT instances rendered from the GT poses, for datasets without ``scene_gt_info.json``.

DIMO ships no ``scene_gt_info.json`` and no test depth, so BOP's targets (objects with
``visib_fract >= 0.1``) must come from rendering. For each image the whole pile is rendered at once
(every GT instance: target parts and the carrier, ids >= 100, which occludes them) and the visible
fraction computed as everywhere else (:func:`bop_cender.visibility.pile_visibility`). Without test depth
there is no sensor depth test: the front-most surface is what is visible.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from bop_cender.eval.ground_truth import ImageGt
from bop_cender.eval.targets import VisibFracts
from bop_cender.meshes import MeshCache
from bop_cender.progress import progress_bar


def rendered_visib_fracts(images: Iterable[ImageGt], meshes: MeshCache, progress: bool = True) -> VisibFracts:
    """``(scene_int, im_id) -> {gt_id: visib_fract}`` for every instance of every image.

    Images with the same instance list and size (the views of one DIMO scene) are rendered in one batch.
    """
    # The renderer (torch) is imported here, not at the top: scoring a dataset with a targets file never
    # needs it in this process (its VSD renders may run in another, see bop_cender.eval.render_process).
    from bop_cender.visibility import pile_visibility

    groups: dict[tuple, list[ImageGt]] = {}
    for image in images:
        signature = (image.scene_key, image.width, image.height, tuple((g.gt_id, g.obj_id) for g in image.instances))
        groups.setdefault(signature, []).append(image)
    out: VisibFracts = {}
    bar = progress_bar(
        total=sum(len(g) for g in groups.values()), desc="visibility", unit="image", disable=not progress
    )
    for group in groups.values():
        first = group[0]
        if not first.instances:
            out.update({im.key: {} for im in group})
            bar.update(len(group))
            continue
        obj_ids = [g.obj_id for g in first.instances]
        T = np.stack([np.stack([g.T_cam_model for g in im.instances]) for im in group])  # (V, M, 4, 4)
        K = np.stack([im.K for im in group])  # (V, 3, 3)
        fract = pile_visibility([meshes(o) for o in obj_ids], T, K, first.height, first.width).fract  # (V, M)
        for v, im in enumerate(group):
            out[im.key] = {g.gt_id: float(fract[v, m]) for m, g in enumerate(im.instances)}
        bar.update(len(group))
    bar.close()
    return out
