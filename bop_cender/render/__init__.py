"""The one batched renderer (depth, normals, instance ids) for CPU and CUDA, and curvature maps.

Public API:

- :func:`prepare_mesh` / :class:`RenderMesh`, :func:`pack_meshes` / :class:`PackedMeshes`;
- :func:`render_scene` (several objects, full frame), :func:`render_objects_separately` (each object
  alone), :func:`render_candidates` (pose candidates of one mesh in square windows);
- :func:`curvature` (the paper's curvature map of rendered normals).

The cost function's tight-window path is :mod:`bop_cender.render.candidate_curvature`, used by
:meth:`bop_cender.pose.backend.Backend.candidate_costs`. Which code draws is a backend object
(:mod:`bop_cender.render.backend`, the ``backend`` argument of the entry points): by default (``auto``) the compiled
loop of :mod:`bop_cender.render.compiled_raster` on the CPU (the torch pipeline's bits, without its per-call
operators) and the kernel of :mod:`bop_cender.render.cuda_render` on CUDA; the torch pipeline
(:mod:`bop_cender.render.raster`, :mod:`bop_cender.render.scanline`, :mod:`bop_cender.render.resolve`) where they
cannot run and where geometry crosses the near plane (``torch``: always).
"""

from bop_cender.render.curvature import curvature
from bop_cender.render.mesh import PackedMeshes, RenderMesh, pack_meshes, prepare_mesh
from bop_cender.render.raster import DEFAULT_NEAR
from bop_cender.render.rasterizer import (
    CandidateRender,
    ObjectsRender,
    SceneRender,
    render_candidates,
    render_objects_separately,
    render_scene,
)

__all__ = [
    "DEFAULT_NEAR",
    "CandidateRender",
    "ObjectsRender",
    "PackedMeshes",
    "RenderMesh",
    "SceneRender",
    "curvature",
    "pack_meshes",
    "prepare_mesh",
    "render_candidates",
    "render_objects_separately",
    "render_scene",
]
