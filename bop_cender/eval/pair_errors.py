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
#: Pairs per MSSD/MSPD batch: MSPD keeps a batch's estimate projections, (pairs x 3 x vertices) float64, so a
#: batch of 2,048 pairs of a 3,000-vertex model holds ~150 MB per worker, whatever the file's size (50,000 estimates
#: in one batch per object peaked at 3.4 GB).
MAX_BATCH_PAIRS = 2048


@dataclass(frozen=True)
class Beyond:
    """Where a scorer stops needing exact errors: MSSD ``mssd_mm[obj_id]`` and MSPD ``mspd_px`` or more are ``inf``."""

    mssd_mm: Mapping[int, float]
    mspd_px: float


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
    beyond: Beyond | None = None,
) -> PairErrors:
    """MSSD, MSPD and (when ``vsd_delta`` is given) VSD of every pair.

    Args:
        pairs: the pairs.
        models: evaluation models by obj_id (``models_eval``: vertices, diameter, symmetries).
        meshes: meshes of the same models (VSD renders).
        vsd_delta: VSD misalignment tolerance (mm); None skips VSD (no test depth).
        taus: VSD tolerances, fractions of the diameter.
        renderer: who renders for VSD; None = :data:`WORKERS` threads of this process.
        beyond: MSSD (mm, per object) and MSPD (px) values at or above which a pair's error is ``inf``, not
            computed (BOP'24 detection: above its largest thresholds); None: every error exact (BOP'19).
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
        if vsd_delta is None:  # nothing else to do: both workers on MSSD/MSPD
            out_mssd, out_mspd = _mssd_mspd(pairs, models, progress, beyond, pool)
            return PairErrors(out_mssd, out_mspd, None, None)
        geometric = pool.submit(_mssd_mspd, pairs, models, progress, beyond)
        out_vsd = None
        if vsd_delta is not None:
            taus = np.asarray(taus, np.float64)
            out_vsd = pair_vsd(pairs, models, meshes, float(vsd_delta), taus, renderer, progress)
        out_mssd, out_mspd = geometric.result()
    return PairErrors(out_mssd, out_mspd, out_vsd, None if out_vsd is None or renderer is None else renderer.describe())


def _mssd_mspd(
    pairs: Pairs,
    models: Mapping[int, ObjectModel],
    progress: bool,
    beyond: Beyond | None = None,
    pool: ThreadPoolExecutor | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """MSSD (mm, inf = early-out or beyond) and MSPD (px, inf = beyond) of every pair, batched per object.

    ``pool``: the batches (each object's pairs in :data:`WORKERS` parts) run on its threads (NumPy releases the GIL
    in the heavy loops): for a scorer with nothing else to do (BOP'24, no VSD); None: one after another here.
    """
    P = len(pairs)
    out_mssd = np.full(P, np.inf)
    out_mspd = np.zeros(P)
    K = np.stack([im.K for im in pairs.images])[pairs.image] if P else np.zeros((0, 3, 3))
    parts = 1 if pool is None else WORKERS
    batches = []
    for obj_id in sorted(set(pairs.obj_id.tolist())):
        rows = np.flatnonzero(pairs.obj_id == obj_id)
        n = max(parts, -(-len(rows) // MAX_BATCH_PAIRS))  # MSPD holds (pairs x vertices) projections of a batch
        batches += [part for part in np.array_split(rows, n) if part.size]

    def run(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        obj_id = int(pairs.obj_id[rows[0]])
        model = models[obj_id]
        pts = eval_vertices(model)
        sym_R, sym_t = model.symmetry_transforms()
        R_e, t_e = pairs.T_est[rows, :3, :3], pairs.T_est[rows, :3, 3]
        R_g, t_g = pairs.T_gt[rows, :3, :3], pairs.T_gt[rows, :3, 3]
        far_mm, far_px = (None, None) if beyond is None else (beyond.mssd_mm[obj_id], beyond.mspd_px)
        e_mssd = mssd(R_e, t_e, R_g, t_g, hull_vertices(pts), sym_R, sym_t, diameter=model.diameter, beyond=far_mm)
        return rows, e_mssd, mspd(R_e, t_e, R_g, t_g, K[rows], pts, sym_R, sym_t, beyond=far_px)

    done = map(run, batches) if pool is None else pool.map(run, batches)
    for rows, e_mssd, e_mspd in progress_bar(done, total=len(batches), desc="MSSD/MSPD", unit="batch",
                                              disable=not progress, leave=False):  # fmt: skip
        out_mssd[rows] = e_mssd
        out_mspd[rows] = e_mspd
    return out_mssd, out_mspd
