"""VSD of every (estimate, GT) pair: plan the depth renders, compute VSD image by image as they arrive.

The toolkit renders each pair's two poses and reads the test depth once per pair. Here:

- pairs whose bounding-sphere projections do not overlap get 1.0 for every tau without rendering
  (the toolkit's early-out);
- each distinct estimated pose and each distinct GT pose is rendered once (several pairs share them);
- the images are cut into chunks of about :data:`CHUNK_POSES` poses, and each chunk into one
  :class:`~bop_cender.eval.render_process.RenderJob` per object and image size; as soon as every job of
  a chunk is back from the renderer (threads or a render process), the chunk's images are scored: each
  test depth image is read once, every pair compared in the window covering both silhouettes, and the
  crops dropped. VSD thus overlaps the renders, and memory holds a few chunks, not the whole dataset.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from bop_cender.data.bop_io import load_depth
from bop_cender.data.types import ObjectModel
from bop_cender.errors import DatasetError
from bop_cender.eval.ground_truth import ImageGt
from bop_cender.eval.pairs import Pairs
from bop_cender.eval.render_crops import DepthCrops, paste, union_window
from bop_cender.eval.render_process import DepthRenderer, RenderJob
from bop_cender.eval.vsd import overlapping_sphere_projections, vsd
from bop_cender.meshes import MeshCache
from bop_cender.progress import progress_bar

#: Poses per chunk of images (about 50 per object and job with T-LESS's mix: enough to fill the rasteriser).
CHUNK_POSES = 320

#: Where one render of a pair lies: (job index, index inside the job).
_Slot = tuple[int, int]


@dataclass(frozen=True)
class RenderPlan:
    """The renders VSD needs, grouped so that images can be scored as their renders arrive.

    Attributes:
        jobs: the render jobs, chunk after chunk.
        job_chunk: ``(J,)`` chunk of each job.
        chunk_images: per chunk, ``{image index: [pair indices]}``.
        slots: per pair (of those rendered), the estimate's and the GT's render.
    """

    jobs: list[RenderJob]
    job_chunk: np.ndarray
    chunk_images: list[dict[int, list[int]]]
    slots: dict[int, tuple[_Slot, _Slot]]


def pair_vsd(
    pairs: Pairs,
    models: Mapping[int, ObjectModel],
    meshes: MeshCache,
    delta: float,
    taus: np.ndarray,
    renderer: DepthRenderer,
    progress: bool = True,
) -> np.ndarray:
    """VSD ``(P, len(taus))`` of every pair.

    Args:
        pairs: the pairs (poses, images, objects).
        models: evaluation models by obj_id (diameters).
        meshes: their meshes.
        delta: VSD tolerance (mm).
        taus: tolerances (fractions of the diameter).
        renderer: who renders (:class:`~bop_cender.eval.render_process.ThreadRenderer` or
            :class:`~bop_cender.eval.render_process.RenderProcess`).
    """
    P = len(pairs)
    out = np.ones((P, len(taus)))
    overlap = np.zeros(P, dtype=bool)
    for obj_id in set(pairs.obj_id.tolist()):
        rows = np.flatnonzero(pairs.obj_id == obj_id)
        radius = 0.5 * models[obj_id].diameter
        overlap[rows] = overlapping_sphere_projections(radius, pairs.T_est[rows, :3, 3], pairs.T_gt[rows, :3, 3])
    todo = np.flatnonzero(overlap)
    if todo.size == 0:
        return out
    diameters = np.array([models[o].diameter for o in pairs.obj_id.tolist()])
    plan = plan_renders(pairs, todo)
    remaining = np.bincount(plan.job_chunk, minlength=len(plan.chunk_images))
    received: dict[int, DepthCrops] = {}
    with progress_bar(total=int(todo.size), desc="VSD", unit="pair", disable=not progress, leave=False) as bar:
        for j, crops in renderer.render(plan.jobs, meshes):
            received[j] = crops
            c = int(plan.job_chunk[j])
            remaining[c] -= 1
            if remaining[c]:
                continue
            for i, members in plan.chunk_images[c].items():
                image = pairs.images[i]
                depth = _test_depth(image)
                for p in members:
                    (je, ke), (jg, kg) = plan.slots[p]
                    est, gt = received[je], received[jg]
                    out[p] = _vsd_in_union(
                        depth, est.depth[ke], est.window(ke), gt.depth[kg], gt.window(kg), image.K,
                        delta, taus, diameters[p],
                    )  # fmt: skip
                bar.update(len(members))
            for j_done in np.flatnonzero(plan.job_chunk == c).tolist():
                del received[j_done]
    return out


def plan_renders(pairs: Pairs, rows: np.ndarray, chunk_poses: int = CHUNK_POSES) -> RenderPlan:
    """Render jobs for the pairs ``rows``: images in order, cut into chunks of about ``chunk_poses`` distinct poses."""
    by_image: dict[int, list[int]] = {}
    for p in rows.tolist():
        by_image.setdefault(int(pairs.image[p]), []).append(p)
    jobs: list[RenderJob] = []
    job_chunk: list[int] = []
    chunk_images: list[dict[int, list[int]]] = []
    slots: dict[int, tuple[_Slot, _Slot]] = {}
    chunk: dict[int, list[int]] = {}
    poses = 0
    for i in sorted(by_image):
        chunk[i] = by_image[i]
        poses += len(by_image[i]) + len({int(pairs.gt_id[p]) for p in by_image[i]})  # at most this many
        if poses >= chunk_poses:
            _add_chunk(pairs, chunk, len(chunk_images), jobs, job_chunk, slots)
            chunk_images.append(chunk)
            chunk, poses = {}, 0
    if chunk:
        _add_chunk(pairs, chunk, len(chunk_images), jobs, job_chunk, slots)
        chunk_images.append(chunk)
    return RenderPlan(jobs, np.asarray(job_chunk, dtype=np.int64), chunk_images, slots)


def _add_chunk(
    pairs: Pairs,
    chunk: dict[int, list[int]],
    c: int,
    jobs: list[RenderJob],
    job_chunk: list[int],
    slots: dict[int, tuple[_Slot, _Slot]],
) -> None:
    """One job per (object, image size) of the chunk's pairs, each distinct estimate and GT pose once."""
    groups: dict[tuple[int, int, int], dict[tuple, int]] = {}
    poses: dict[tuple[int, int, int], tuple[list[np.ndarray], list[np.ndarray]]] = {}
    keyed: dict[int, tuple[tuple, tuple, tuple]] = {}
    for i, members in chunk.items():
        image = pairs.images[i]
        for p in members:
            group = (int(pairs.obj_id[p]), image.height, image.width)
            index = groups.setdefault(group, {})
            T_list, K_list = poses.setdefault(group, ([], []))
            keys = (("e", int(pairs.est[p])), ("g", image.key, int(pairs.gt_id[p])))
            for key, T in zip(keys, (pairs.T_est[p], pairs.T_gt[p]), strict=True):
                if key not in index:
                    index[key] = len(T_list)
                    T_list.append(T)
                    K_list.append(image.K)
            keyed[p] = (group, *keys)
    job_of = {}
    for group, (T_list, K_list) in poses.items():
        job_of[group] = len(jobs)
        jobs.append(RenderJob(group[0], np.stack(T_list), np.stack(K_list), group[1], group[2]))
        job_chunk.append(c)
    for p, (group, key_e, key_g) in keyed.items():
        j = job_of[group]
        slots[p] = ((j, groups[group][key_e]), (j, groups[group][key_g]))


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
    win = union_window(we, wg)
    if win is None:
        return np.ones(len(taus))
    test = depth[win[0] : win[2], win[1] : win[3]]
    return vsd(test, paste(de, we, win), paste(dg, wg, win), K, delta, taus, diameter, True, window=win)


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
