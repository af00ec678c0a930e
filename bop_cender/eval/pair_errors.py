"""Raw BOP errors (MSSD mm, MSPD px, VSD per tau) of every (kept estimate, GT of its object) pair.

The toolkit computes each pair in a Python loop (``eval_calc_errors.py``), 3 passes and one renderer
call per VSD pair. Here the pairs are batched per object:

- MSSD over the convex-hull vertices of the ``models_eval`` PLY, read as the toolkit reads it
  (:mod:`bop_cender.eval.model_points`; same maximum as all vertices, see
  :func:`bop_cender.eval.errors.hull_vertices`), ``inf`` when ``||t_e - t_g|| >= diameter``;
- MSPD over all vertices (no early-out, as the toolkit);
- VSD: pairs whose bounding-sphere projections do not overlap get 1.0 for every tau without rendering
  (the toolkit's early-out); the others render each estimated pose and each GT pose once (several
  pairs share them), cut to their silhouettes, and compare in the window covering both, image by
  image, so each test depth image is read once.
"""

from __future__ import annotations

from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from bop_cender.data.bop_io import load_depth
from bop_cender.data.types import ObjectModel
from bop_cender.errors import DatasetError
from bop_cender.eval.depth_render import DepthCrops, MeshCache, render_depth_crops, single_threaded_torch
from bop_cender.eval.errors import hull_vertices, mspd, mssd
from bop_cender.eval.ground_truth import ImageGt
from bop_cender.eval.model_points import eval_vertices
from bop_cender.eval.vsd import VSD_TAUS, overlapping_sphere_projections, vsd

#: Worker threads (the benchmark target is two cores) and poses per render job.
WORKERS = 2
RENDER_BATCH = 96


@dataclass(frozen=True, eq=False)
class Pairs:
    """P (estimate, GT) pairs, as arrays.

    Attributes:
        est: ``(P,)`` index of the estimate (in the scorer's kept list); several pairs share one.
        image: ``(P,)`` index into ``images``.
        gt_id: ``(P,)`` the GT instance's gt_id in its image.
        obj_id: ``(P,)`` object id.
        T_est, T_gt: ``(P, 4, 4)`` model-to-camera poses.
        images: the images the pairs refer to.
    """

    est: np.ndarray
    image: np.ndarray
    gt_id: np.ndarray
    obj_id: np.ndarray
    T_est: np.ndarray
    T_gt: np.ndarray
    images: list[ImageGt]

    def __len__(self) -> int:
        return len(self.est)


@dataclass(frozen=True)
class PairErrors:
    """Raw errors ``(P,)`` per pair: MSSD (mm, inf = early-out), MSPD (px), VSD ``(P, taus)`` or None."""

    mssd: np.ndarray
    mspd: np.ndarray
    vsd: np.ndarray | None


def pair_errors(
    pairs: Pairs,
    models: Mapping[int, ObjectModel],
    meshes: MeshCache,
    vsd_delta: float | None,
    taus: np.ndarray = VSD_TAUS,
    progress: bool = True,
) -> PairErrors:
    """MSSD, MSPD and (when ``vsd_delta`` is given) VSD of every pair.

    Args:
        pairs: the pairs.
        models: evaluation models by obj_id (``models_eval``: vertices, diameter, symmetries).
        meshes: render meshes of the same models (VSD).
        vsd_delta: VSD misalignment tolerance (mm); None skips VSD (no test depth).
        taus: VSD tolerances, fractions of the diameter.
    """
    # Two workers share MSSD/MSPD (NumPy) and the VSD renders (torch, one intra-op thread each: the
    # rasteriser hardly scales with threads, and OpenMP threads spinning beside a second worker slow both
    # down many times); both release the GIL in their heavy loops, so two cores are used.
    with single_threaded_torch(), ThreadPoolExecutor(max_workers=WORKERS) as pool:
        geometric = pool.submit(_mssd_mspd, pairs, models, progress)
        out_vsd = None
        if vsd_delta is not None:
            taus = np.asarray(taus, np.float64)
            out_vsd = _vsd_errors(pairs, models, meshes, float(vsd_delta), taus, progress, pool)
        out_mssd, out_mspd = geometric.result()
    return PairErrors(out_mssd, out_mspd, out_vsd)


def _mssd_mspd(pairs: Pairs, models: Mapping[int, ObjectModel], progress: bool) -> tuple[np.ndarray, np.ndarray]:
    """MSSD (mm, inf = early-out) and MSPD (px) of every pair, batched per object."""
    P = len(pairs)
    out_mssd = np.full(P, np.inf)
    out_mspd = np.zeros(P)
    obj_ids = sorted(set(pairs.obj_id.tolist()))
    K = np.stack([im.K for im in pairs.images])[pairs.image] if P else np.zeros((0, 3, 3))
    for obj_id in tqdm(obj_ids, desc="MSSD/MSPD", unit="object", disable=not progress, leave=False):
        rows = np.flatnonzero(pairs.obj_id == obj_id)
        model = models[obj_id]
        pts = eval_vertices(model)
        sym_R, sym_t = model.symmetry_transforms()
        R_e, t_e = pairs.T_est[rows, :3, :3], pairs.T_est[rows, :3, 3]
        R_g, t_g = pairs.T_gt[rows, :3, :3], pairs.T_gt[rows, :3, 3]
        out_mssd[rows] = mssd(R_e, t_e, R_g, t_g, hull_vertices(pts), sym_R, sym_t, diameter=model.diameter)
        out_mspd[rows] = mspd(R_e, t_e, R_g, t_g, K[rows], pts, sym_R, sym_t)
    return out_mssd, out_mspd


def _vsd_errors(
    pairs: Pairs,
    models: Mapping[int, ObjectModel],
    meshes: MeshCache,
    delta: float,
    taus: np.ndarray,
    progress: bool,
    pool: ThreadPoolExecutor,
) -> np.ndarray:
    P = len(pairs)
    out = np.ones((P, len(taus)))
    diameters = np.array([models[o].diameter for o in pairs.obj_id.tolist()])
    overlap = np.zeros(P, dtype=bool)
    for obj_id in set(pairs.obj_id.tolist()):
        rows = np.flatnonzero(pairs.obj_id == obj_id)
        radius = 0.5 * models[obj_id].diameter
        overlap[rows] = overlapping_sphere_projections(radius, pairs.T_est[rows, :3, 3], pairs.T_gt[rows, :3, 3])
    todo = np.flatnonzero(overlap)
    if todo.size == 0:
        return out
    est_crop, gt_crop = _render_pairs(pairs, todo, meshes, progress, pool)
    by_image: dict[int, list[int]] = {}
    for p in todo.tolist():
        by_image.setdefault(int(pairs.image[p]), []).append(p)

    def image_vsd(i: int) -> None:  # one image: read its depth once, then every pair in it
        image = pairs.images[i]
        depth = _test_depth(image)
        for p in by_image[i]:
            de, we = est_crop[p]
            dg, wg = gt_crop[p]
            out[p] = _vsd_in_union(depth, de, we, dg, wg, image.K, delta, taus, diameters[p])

    order = sorted(by_image)
    for _ in tqdm(
        pool.map(image_vsd, order), total=len(order), desc="VSD", unit="image", disable=not progress, leave=False
    ):
        pass
    return out


_Crop = tuple[np.ndarray, tuple[int, int, int, int] | None]


def _render_pairs(
    pairs: Pairs, rows: np.ndarray, meshes: MeshCache, progress: bool, pool: ThreadPoolExecutor
) -> tuple[dict[int, _Crop], dict[int, _Crop]]:
    """Render each distinct estimate pose and GT pose of ``rows`` once (batches spread over ``pool``); crops by pair."""
    est_crop: dict[int, _Crop] = {}
    gt_crop: dict[int, _Crop] = {}
    groups: dict[tuple[int, int, int], list[int]] = {}
    for p in rows.tolist():
        image = pairs.images[int(pairs.image[p])]
        groups.setdefault((int(pairs.obj_id[p]), image.height, image.width), []).append(p)
    jobs = []
    for (obj_id, height, width), members in groups.items():
        keys: dict[tuple, int] = {}
        poses, Ks, owner = [], [], []
        for p in members:
            image = pairs.images[int(pairs.image[p])]
            for kind, key, T in (
                ("e", int(pairs.est[p]), pairs.T_est[p]),
                ("g", (image.key, int(pairs.gt_id[p])), pairs.T_gt[p]),
            ):
                full_key = (kind, key)
                if full_key not in keys:
                    keys[full_key] = len(poses)
                    poses.append(T)
                    Ks.append(image.K)
                owner.append((p, kind, keys[full_key]))
        mesh = meshes(obj_id)  # prepared here: the cache is not shared between threads
        T_all, K_all = np.stack(poses), np.stack(Ks)
        order = np.argsort(T_all[:, 2, 3], kind="stable")  # similar distances together: similar window sizes
        batches = [order[i : i + RENDER_BATCH] for i in range(0, len(order), RENDER_BATCH)]
        futures = [pool.submit(render_depth_crops, mesh, T_all[b], K_all[b], height, width) for b in batches]
        jobs.append((owner, batches, futures))
    bar = tqdm(total=len(rows), desc="VSD renders", unit="pair", disable=not progress, leave=False)
    for owner, batches, futures in jobs:
        where: dict[int, _Crop] = {}
        for b, future in zip(batches, futures, strict=True):
            crops: DepthCrops = future.result()
            for k, pose in enumerate(b.tolist()):
                where[pose] = (crops.depth[k], crops.window(k))
        for p, kind, k in owner:
            (est_crop if kind == "e" else gt_crop)[p] = where[k]
        bar.update(len({p for p, _, _ in owner}))
    bar.close()
    return est_crop, gt_crop


def _vsd_in_union(
    depth: np.ndarray,
    de: np.ndarray,
    we: tuple[int, int, int, int] | None,
    dg: np.ndarray,
    wg: tuple[int, int, int, int] | None,
    K: np.ndarray,
    delta: float,
    taus: np.ndarray,
    diameter: float,
) -> np.ndarray:
    """VSD of one pair in the window covering both silhouettes (1 for every tau when both are empty)."""
    wins = [w for w in (we, wg) if w is not None]
    if not wins:
        return np.ones(len(taus))
    win = (min(w[0] for w in wins), min(w[1] for w in wins), max(w[2] for w in wins), max(w[3] for w in wins))
    shape = (win[2] - win[0], win[3] - win[1])
    est = _paste(de, we, win, shape)
    gt = _paste(dg, wg, win, shape)
    test = depth[win[0] : win[2], win[1] : win[3]]
    return vsd(test, est, gt, K, delta, taus, diameter, True, window=win)


def _paste(
    crop: np.ndarray, where: tuple[int, int, int, int] | None, win: tuple[int, int, int, int], shape: tuple[int, int]
) -> np.ndarray:
    if where == win:
        return crop
    out = np.zeros(shape, dtype=np.float32)
    if where is not None:
        out[where[0] - win[0] : where[2] - win[0], where[1] - win[1] : where[3] - win[1]] = crop
    return out


def _test_depth(image: ImageGt) -> np.ndarray:
    """The image's test depth in mm ``(H, W)`` float32 (PNG x depth_scale, the toolkit's float32 product)."""
    if image.depth_path is None or image.depth_scale is None:
        raise DatasetError(f"image {image.im_id} of scene {image.scene_id} has no depth image (VSD needs it)")
    depth = load_depth(image.depth_path, image.depth_scale)
    if depth.shape != (image.height, image.width):
        raise DatasetError(
            f"depth image is {depth.shape[1]}x{depth.shape[0]}, expected {image.width}x{image.height}",
            file=image.depth_path,
        )
    return depth
