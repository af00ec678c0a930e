"""Model geometry for evaluation: vertices for MSSD / MSPD exactly as the BOP toolkit reads them from
``models_eval`` PLY files (the meshes for the VSD renders: :class:`bop_cender.meshes.MeshCache`).

The toolkit's ``inout.load_ply`` turns the text of an ASCII PLY into float64 with Python's
``float()``; trimesh (our mesh loader) reads an ASCII ``property float`` as float32 first. The two
differ by ~1e-7 relative (e.g. ``18.70469475`` vs ``18.704694747924805``), which moves MSSD by ~1e-9 mm,
enough to flip an error lying on a threshold. So evaluation reads ASCII vertices here, as the toolkit
does; binary PLYs hold float32/float64 values that both loaders read alike.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bop_cender.data.models import check_extent
from bop_cender.data.ply_ascii import ascii_vertices
from bop_cender.data.types import ObjectModel


def eval_vertices(model: ObjectModel) -> np.ndarray:
    """``(N, 3)`` float64 vertices of ``model`` as the toolkit's ``load_ply`` returns them (read-only).

    Raises:
        DatasetError: the mesh's bounding box is not its ``models_info.json`` entry's (:func:`check_extent`)."""
    ascii_pts = ascii_vertices(str(Path(model.path).resolve()))
    if ascii_pts is not None:
        check_extent(model, ascii_pts)
        return ascii_pts
    pts = np.array(model.mesh.vertices, dtype=np.float64)
    check_extent(model, pts)
    pts.setflags(write=False)
    return pts
