"""Meshes for the renderer, read and prepared once per object id: the one mesh cache type.

Above the data layer and the renderer, below the synthetic generator and evaluation (both use it).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from bop_cender.data.models import check_extent
from bop_cender.data.ply_ascii import MeshArrays, ascii_mesh
from bop_cender.data.types import ObjectModel

if TYPE_CHECKING:
    from bop_cender.render.mesh import RenderMesh


@dataclass
class MeshCache:
    """Meshes of a model set, read once per object id on first use, and the renderer's meshes prepared once.

    The one mesh cache: evaluation's (dataset models, :class:`~bop_cender.data.types.ObjectModel`) and the
    synthetic generator's (procedural parts). Reading needs no torch (:meth:`arrays`), so a scorer that renders
    in another process (:mod:`bop_cender.eval.render_process`) never imports it; :meth:`__call__` prepares the
    renderer's mesh (torch) on first use.

    Attributes:
        models: by obj_id, anything with a ``mesh`` (trimesh); with a ``path`` too, an ASCII PLY there is
            read without trimesh, its vertices exactly as the toolkit reads them.
    """

    models: Mapping[int, Any]
    _arrays: dict[int, MeshArrays] = field(default_factory=dict, repr=False)
    _meshes: dict[int, RenderMesh] = field(default_factory=dict, repr=False)

    def arrays(self, obj_id: int) -> MeshArrays:
        """Vertices and triangles of object ``obj_id``: an ASCII PLY without trimesh (faster cold start), else trimesh."""
        if obj_id not in self._arrays:
            model = self.models[obj_id]
            path = getattr(model, "path", None)
            mesh = None if path is None else ascii_mesh(path)
            if mesh is None:
                mesh = MeshArrays(np.asarray(model.mesh.vertices, np.float64), np.asarray(model.mesh.faces, np.int64))
            if isinstance(model, ObjectModel):  # a dataset's model: its mesh must be the size its entry says
                check_extent(model, mesh.vertices)
            self._arrays[obj_id] = mesh
        return self._arrays[obj_id]

    def __call__(self, obj_id: int) -> RenderMesh:
        """The renderer's mesh of object ``obj_id`` (CPU), prepared once."""
        if obj_id not in self._meshes:
            from bop_cender.render.mesh import prepare_mesh

            self._meshes[obj_id] = prepare_mesh(self.arrays(obj_id))
        return self._meshes[obj_id]

    def many(self, obj_ids: Sequence[int]) -> list[RenderMesh]:
        """The renderer's meshes of several objects (repeats allowed), in order."""
        return [self(i) for i in obj_ids]
