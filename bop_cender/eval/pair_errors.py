"""Raw BOP errors (MSSD mm, MSPD px, VSD per tau) of every (kept estimate, GT of its object) pair.

The toolkit computes each pair in a Python loop (``eval_calc_errors.py``), 3 passes and one renderer
call per VSD pair. Here the pairs are batched per object:

- MSSD over the convex-hull vertices of the ``models_eval`` PLY, read as the toolkit reads it
  (:mod:`bop_cender.eval.model_points`; same maximum as all vertices, see
  :func:`bop_cender.eval.pose_errors.hull_vertices`), ``inf`` when ``||t_e - t_g|| >= diameter``;
- MSPD over all vertices (no early-out, as the toolkit);
- VSD (:mod:`bop_cender.eval.pair_vsd`): each distinct pose rendered once, by worker threads or by a
  render process started before torch was imported (:mod:`bop_cender.eval.render_process`), and
  compared image by image as the renders arrive, while MSSD and MSPD run beside.
"""

from __future__ import annotations

from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from contextlib import ExitStack
from dataclasses import dataclass

import numpy as np

from bop_cender.data.types import ObjectModel
from bop_cender.eval.model_points import eval_vertices
from bop_cender.eval.pair_vsd import pair_vsd
from bop_cender.eval.pairs import Pairs
from bop_cender.eval.pose_errors import hull_vertices, mspd, mssd
from bop_cender.eval.render_process import DepthRenderer, ThreadRenderer
from bop_cender.eval.vsd import VSD_TAUS
from bop_cender.meshes import MeshCache
from bop_cender.progress import progress_bar

#: Worker threads (the benchmark target is two cores).
WORKERS = 2


@dataclass(frozen=True)
class PairErrors:
    """Raw errors ``(P,)`` per pair: MSSD (mm, inf = early-out), MSPD (px), VSD ``(P, taus)`` or None.

    ``vsd_renders`` says who rendered the VSD depth (None without VSD).
    """

    mssd: np.ndarray
    mspd: np.ndarray
    vsd: np.ndarray | None
    vsd_renders: str | None = None


def pair_errors(
    pairs: Pairs,
    models: Mapping[int, ObjectModel],
    meshes: MeshCache,
    vsd_delta: float | None,
    taus: np.ndarray = VSD_TAUS,
    progress: bool = True,
    renderer: DepthRenderer | None = None,
) -> PairErrors:
    """MSSD, MSPD and (when ``vsd_delta`` is given) VSD of every pair.

    Args:
        pairs: the pairs.
        models: evaluation models by obj_id (``models_eval``: vertices, diameter, symmetries).
        meshes: meshes of the same models (VSD renders).
        vsd_delta: VSD misalignment tolerance (mm); None skips VSD (no test depth).
        taus: VSD tolerances, fractions of the diameter.
        renderer: who renders for VSD; None = :data:`WORKERS` threads of this process.
    """
    with ExitStack() as stack:
        pool = stack.enter_context(ThreadPoolExecutor(max_workers=WORKERS))
        if renderer is None and vsd_delta is not None:
            # Renders on the pool, one torch intra-op thread each: the rasteriser hardly scales with threads,
            # and OpenMP threads spinning beside a second worker slow both down many times.
            from bop_cender.eval.depth_render import single_threaded_torch

            stack.enter_context(single_threaded_torch())
            renderer = ThreadRenderer(pool)
        # MSSD/MSPD (NumPy, GIL released in its heavy loops) on a worker while this thread computes VSD as
        # the renders arrive.
        geometric = pool.submit(_mssd_mspd, pairs, models, progress)
        out_vsd = None
        if vsd_delta is not None:
            taus = np.asarray(taus, np.float64)
            out_vsd = pair_vsd(pairs, models, meshes, float(vsd_delta), taus, renderer, progress)
        out_mssd, out_mspd = geometric.result()
    return PairErrors(out_mssd, out_mspd, out_vsd, None if out_vsd is None or renderer is None else renderer.describe())


def _mssd_mspd(pairs: Pairs, models: Mapping[int, ObjectModel], progress: bool) -> tuple[np.ndarray, np.ndarray]:
    """MSSD (mm, inf = early-out) and MSPD (px) of every pair, batched per object."""
    P = len(pairs)
    out_mssd = np.full(P, np.inf)
    out_mspd = np.zeros(P)
    obj_ids = sorted(set(pairs.obj_id.tolist()))
    K = np.stack([im.K for im in pairs.images])[pairs.image] if P else np.zeros((0, 3, 3))
    for obj_id in progress_bar(obj_ids, desc="MSSD/MSPD", unit="object", disable=not progress, leave=False):
        rows = np.flatnonzero(pairs.obj_id == obj_id)
        model = models[obj_id]
        pts = eval_vertices(model)
        sym_R, sym_t = model.symmetry_transforms()
        R_e, t_e = pairs.T_est[rows, :3, :3], pairs.T_est[rows, :3, 3]
        R_g, t_g = pairs.T_gt[rows, :3, :3], pairs.T_gt[rows, :3, 3]
        out_mssd[rows] = mssd(R_e, t_e, R_g, t_g, hull_vertices(pts), sym_R, sym_t, diameter=model.diameter)
        out_mspd[rows] = mspd(R_e, t_e, R_g, t_g, K[rows], pts, sym_R, sym_t)
    return out_mssd, out_mspd
