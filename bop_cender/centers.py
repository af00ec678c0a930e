"""Stage 2 of CenDerNet (paper, Section 2.2): center heatmaps of several views -> 3D object centres.

1. Peaks: ``skimage.feature.peak_local_max`` above ``peak_threshold`` in each view's center channel.
2. One ray per peak from ``K`` and ``T_cam_world``, through the peak pixel's centre ``(u + 0.5, v + 0.5)``
   (the pixel convention of docs/design.md).
3. For every pair of rays from different views, their closest points (Szeliski): the distance between
   them and the midpoint, all pairs at once. Midpoints of pairs closer than ``d_t`` and in front of both
   cameras are candidates.
4. Candidates closer than ``d_c`` are merged: greedily, best aggregated heatmap score first, into their
   score-weighted mean (a chain of phantom midpoints between two objects cannot pull them together, as
   single-linkage clustering would).
5. Each merged point is refined by maximising its summed, bilinearly sampled heatmap score over the views
   (Nelder-Mead, every candidate in lockstep: :func:`refine_centers`); its per-view scores are kept (stage 3
   reads them as visibility).
6. Points outside every view's frustum, or scoring ``min_view_score`` in fewer than ``min_views`` views,
   are dropped.
7. Selection by peak ownership (ours, :func:`select_centers`): a view's peak explains one centre.
   Greedily, the point with the best summed score over the views where it does not sit on (lie within
   ``peak_match_px`` of) a peak an accepted centre owns is accepted, if ``min_views`` of those views
   score ``min_view_score`` and it sits on at least one peak nobody owns; it then owns the peaks it
   sits on. Refined duplicates of an accepted centre and phantom points where rays of different
   objects cross find their peaks owned and are dropped; two real objects closer than the paper's
   ``d_o`` keep their own peaks and are both kept. With a known object count at most n are accepted,
   none within ``d_o`` of a better one (the paper: the top n by score, none within ``d_o``).

Pure functions on NumPy arrays (float64 geometry, millimetres); :func:`detect_centers` composes them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from skimage.feature import peak_local_max

from bop_cender.geometry.camera import camera_center_in_world
from bop_cender.geometry.sampling import sample_scores
from bop_cender.optim.simplex import batched_nelder_mead
from bop_cender.settings_checks import COUNT, FRACTION_OPEN, NON_NEGATIVE, POSITIVE, Bound, check_settings


@dataclass(frozen=True)
class CenterConfig:
    """Stage-2 settings (paper appendix: d_t = d_c = d_o = 30 mm; see :meth:`paper`; the rest are ours).

    Attributes:
        peak_threshold: minimum heatmap value of a peak (ours: 0.15 of a peak-1 blob, with
            ``min_view_score`` 0.1). A network trained with the focal centre loss predicts sharp but low
            peaks: the shipped DIMO network (``dimo-context``) places 67 parts of 70 with 0.15 and fewer with
            0.3 (seed 9002 test set; with 0.3 its context+focal predecessor reached AR_MSSD<5% 0.380, with
            0.15 0.466, ``results/net/dimo.md``). The oracle's blobs peak at 1: the same centres with either
            (`scripts/eval_centers.py`, 68 of 70 within 5 mm, 1 false).
        peak_min_distance: ``peak_local_max``'s ``min_distance`` (pixels; ours: 2 keeps two close centres apart).
        d_t: maximum distance between two rays for their midpoint to be a candidate (mm).
        d_c: candidates closer than this are merged (mm). Ours: 10; the paper's 30 merges parts that
            touch: on 24 synthetic DIMO-layout piles (oracle heatmaps, `scripts/eval_centers.py`)
            30/30 found 85 of 131 GT centres within 5 mm, 10/10 found 126 (thin shafts lying side by
            side have centres 13-25 mm apart).
        d_o: with a known object count, centres closer than this to a better one are dropped (mm).
            Ours: 5 (paper: 30; we had 10, for the same reason as ``d_c``). Peak ownership now drops
            duplicates, so d_o only guards against one blob with two peaks; 10 dropped real
            neighbours: piled flanges 7.9 and 10.0 mm apart (dimo_val sim 000002_00, dimo_test sim
            000001_00), both refined to within 1 mm and each with its own peaks.
        min_views: a centre must score ``min_view_score`` in at least this many views (a point seen in
            one view only cannot be triangulated; ours: 2).
        min_view_score: see ``min_views`` (ours: 0.1, with ``peak_threshold`` 0.15).
        min_views_unknown_count: ``min_views`` when the object count is not known (ours: 3): two
            rays of different objects often pass within ``d_t`` of each other, and nothing else then
            prunes such phantom points; three views rarely agree by chance.
        peak_match_px: a centre sits on a peak of a view when its projection is within this many pixels
            of that view's nearest peak (ours: 8. 3, about half a DIMO blob's sigma, lost parts at T-LESS's
            720 x 540, where blobs are wider: on a fresh T-LESS-layout test set (seed 4243, 30 images) BOP
            AR 0.850 with 3 against 0.874 with 8, the old top-n's 0.875; on a fresh DIMO-layout set (seed
            4242, 24 scenes) AR_MSSD<5% 0.758 with either, AR_MSSD 0.893 / 0.894, the old top-n's 0.757
            / 0.880). See :func:`select_centers`. Peak ownership
            instead of the paper's top-n by score (oracle heatmaps, known counts,
            `scripts/eval_centers.py`): dimo_test sim 66 -> 68 of 70 GT centres within 5 mm, false
            centres 5 -> 1; dimo_val sim 18 -> 19 of 21, false 3 -> 0 (the remaining four misses have a
            blob in at most one view: almost hidden, visib_fract < 0.1 elsewhere). The top-n had
            preferred a phantom scoring 3.14 in four views, where rays of three other objects cross,
            over a part scoring 2.0 in the two views that show its centre (dimo_test sim 000011_00),
            and filled the places of hidden parts with phantoms. Shipped network's heatmaps: found
            23 -> 24 of 70 (dimo_test sim), 18 -> 19 (real), 12 -> 13 of 21 (dimo_val sim), 6 -> 6
            (real), false 47 -> 42, 52 -> 45, 9 -> 6, 15 -> 14, the same within 20 mm. A stricter
            rule (only views on a free peak count) gave 0 false on oracle maps but lost 4-10 network
            centres within 20 mm: a network blob is often weak or off its peak in some views.
            Without a known count, the duplicates were all kept before (34 centres for 2 objects).
        refine_tol: Nelder-Mead ``xatol`` of the refinement (mm) and its ``fatol`` (score units).
        refine_maxiter: Nelder-Mead iterations per centre (as twice as many evaluations).
        class_agnostic: with several center channels (one per object id, T-LESS), find the centres on their
            class-agnostic map (:func:`class_agnostic_map`: a factored network's sum, else the channels' noisy-OR)
            with the known total count, then
            give each the channel whose map scores it best where that id's count is not used up
            (:func:`assign_channels`). Ours: True; False is each channel alone (the paper's reading). Why: a part
            whose id the network is unsure of spreads its peak over several channels, each then below the peak
            threshold (T-LESS seed 4243, the shipped network: per channel 24 centres for 44 parts, 14 within 5 mm;
            on the sum 34, 17). Measured (2026-12-07, 2-core AMD EPYC, ``results/accuracy/README.md``), BOP AR on
            four T-LESS-layout test sets (seeds 4243, 6161, 7272, 8383): the shipped network 0.477 / 0.584 / 0.408 /
            0.461 -> 0.518 / 0.583 / 0.484 / 0.482, the oracle 0.893 / 0.971 / 0.890 / 0.962 -> 0.935 / 0.972 /
            0.897 / 0.963 (neighbouring parts of different ids no longer cost each other a centre); 9-44 % more
            objects placed with the network (so as much more stage-3 time). One channel (DIMO): no change.
    """

    peak_threshold: float = 0.15
    peak_min_distance: int = 2
    d_t: float = 30.0
    d_c: float = 10.0
    d_o: float = 5.0
    min_views: int = 2
    min_view_score: float = 0.1
    min_views_unknown_count: int = 3
    peak_match_px: float = 8.0
    refine_tol: float = 0.05
    refine_maxiter: int = 200
    class_agnostic: bool = True

    def __post_init__(self) -> None:
        check_settings("centers", self, _CENTER_BOUNDS)

    @staticmethod
    def paper() -> CenterConfig:
        """The paper's values: d_t = d_c = d_o = 30 mm, each channel alone."""
        return CenterConfig(d_t=30.0, d_c=30.0, d_o=30.0, class_agnostic=False)


_CENTER_BOUNDS = {
    "peak_threshold": FRACTION_OPEN,
    "peak_min_distance": COUNT,
    "d_t": POSITIVE,
    "d_c": NON_NEGATIVE,
    "d_o": NON_NEGATIVE,
    "min_views": COUNT,
    "min_view_score": Bound(0.0, 1.0),
    "min_views_unknown_count": COUNT,
    "peak_match_px": POSITIVE,
    "refine_tol": POSITIVE,
    "refine_maxiter": COUNT,
}
"""What each stage-2 setting may be (:func:`~bop_cender.settings_checks.check_settings`)."""


@dataclass(frozen=True, eq=False)
class Center3D:
    """One detected object centre.

    Attributes:
        position: ``(3,)`` float64 world coordinates (mm).
        view_scores: ``(V,)`` heatmap value at its projection in each view (0 outside or behind).
        channel: the center channel it was found in.
        obj_id: the object id of that channel, None when the channel is shared by all objects.
    """

    position: np.ndarray
    view_scores: np.ndarray
    channel: int = 0
    obj_id: int | None = None

    @property
    def score(self) -> float:
        """Aggregated heatmap score: the sum over views (paper: "accumulated for all views")."""
        return float(np.sum(self.view_scores))


def find_peaks(heatmap: np.ndarray, threshold: float, min_distance: int) -> tuple[np.ndarray, np.ndarray]:
    """Local maxima of ``heatmap (H, W)``: continuous image points ``(N, 2)`` (x, y) of the peak pixels'
    centres and their values ``(N,)``, best first."""
    rc = peak_local_max(
        np.asarray(heatmap, dtype=np.float64),
        min_distance=max(1, int(min_distance)),
        threshold_abs=threshold,
        exclude_border=False,
    )
    if len(rc) == 0:
        return np.zeros((0, 2)), np.zeros(0)
    values = heatmap[rc[:, 0], rc[:, 1]].astype(np.float64)
    return np.stack([rc[:, 1] + 0.5, rc[:, 0] + 0.5], axis=1).astype(np.float64), values


def peak_rays(K: np.ndarray, T_cam_world: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-frame origins ``(N, 3)`` and unit directions ``(N, 3)`` of the rays through image points ``xy (N, 2)``."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    homog = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    d_cam = homog @ np.linalg.inv(K).T
    d_world = d_cam @ np.asarray(T_cam_world)[:3, :3]  # R^T d
    d_world /= np.linalg.norm(d_world, axis=1, keepdims=True)
    origin = np.broadcast_to(camera_center_in_world(T_cam_world), d_world.shape).copy()
    return origin, d_world


def closest_points(
    o1: np.ndarray, d1: np.ndarray, o2: np.ndarray, d2: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Closest points of pairs of lines ``o + s d`` (unit ``d``), all ``(..., 3)``.

    Returns:
        ``distance (...)`` between the two closest points, their ``midpoint (..., 3)`` and the ray
        parameters ``s, t (...)`` (distances along each ray, mm). Parallel lines get distance inf.
    """
    w0 = o1 - o2
    b = np.sum(d1 * d2, axis=-1)
    d = np.sum(d1 * w0, axis=-1)
    e = np.sum(d2 * w0, axis=-1)
    denom = 1.0 - b * b
    parallel = denom < 1e-12
    safe = np.where(parallel, 1.0, denom)
    s = (b * e - d) / safe
    t = (e - b * d) / safe
    p1 = o1 + s[..., None] * d1
    p2 = o2 + t[..., None] * d2
    distance = np.where(parallel, np.inf, np.linalg.norm(p1 - p2, axis=-1))
    return distance, (p1 + p2) / 2.0, s, t


def triangulate_pairs(origins: np.ndarray, directions: np.ndarray, view_index: np.ndarray, d_t: float) -> np.ndarray:
    """Midpoints ``(P, 3)`` of every pair of rays from different views that pass within ``d_t`` of each
    other, in front of both cameras. Rays: ``origins, directions (N, 3)``, ``view_index (N,)``."""
    i, j = np.triu_indices(len(origins), k=1)
    keep = view_index[i] != view_index[j]
    i, j = i[keep], j[keep]
    if len(i) == 0:
        return np.zeros((0, 3))
    dist, mid, s, t = closest_points(origins[i], directions[i], origins[j], directions[j])
    ok = (dist < d_t) & (s > 0) & (t > 0)
    return mid[ok]


def merge_candidates(points: np.ndarray, scores: np.ndarray, d_c: float) -> np.ndarray:
    """Greedy merge: the best-scoring unmerged point takes every unmerged point within ``d_c`` and becomes
    their score-weighted mean. ``points (P, 3)``, ``scores (P,)`` -> ``(Q, 3)``, best first."""
    if len(points) == 0:
        return np.zeros((0, 3))
    order = np.argsort(-scores, kind="stable")
    pts, sc = points[order], np.maximum(scores[order], 1e-12)
    free = np.ones(len(pts), dtype=bool)
    merged = []
    for k in range(len(pts)):
        if not free[k]:
            continue
        # one row of distances per merged point, not the (P, P, 3) differences of all pairs (2.4 GB at P = 10,000)
        group = free & (np.linalg.norm(pts - pts[k], axis=1) < d_c)
        free &= ~group
        w = sc[group]
        merged.append((pts[group] * w[:, None]).sum(0) / w.sum())
    return np.asarray(merged)


def refine_centers(
    points: np.ndarray, heatmaps: np.ndarray, Ks: np.ndarray, T_cam_world: np.ndarray, config: CenterConfig
) -> np.ndarray:
    """Nelder-Mead maximisation of the summed heatmap score of each of ``points (Q, 3)`` (initial simplex
    5 mm), all Q simplices stepping in lockstep (:func:`bop_cender.optim.simplex.batched_nelder_mead`: each
    step samples the heatmaps at every simplex's new points in one call). Returns ``(Q, 3)``.

    Why batched: a pile gives a few hundred merged candidates, and one ``scipy.optimize.minimize`` each
    spent 3.6 s of a 7-view, 8-part scene in per-call overhead (``results/bench/run_*``)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0:
        return points

    def negative(x: np.ndarray) -> np.ndarray:
        return -sample_scores(x, heatmaps, Ks, T_cam_world).sum(1)

    inf = np.full(3, np.inf)
    # about two evaluations per Nelder-Mead iteration: the budget of ``refine_maxiter`` iterations
    x, _, _ = batched_nelder_mead(
        negative, points, np.full(3, 5.0), -inf, inf, config.refine_tol, 1e-4, 2 * config.refine_maxiter
    )
    return x


def detect_centers(
    center_maps: np.ndarray,
    Ks: np.ndarray,
    T_cam_world: np.ndarray,
    config: CenterConfig,
    channel_obj_ids: Sequence[int] | None = None,
    known_counts: Mapping[int, int] | None = None,
    exclusive_channels: bool = False,
) -> list[Center3D]:
    """3D centres from the center heatmaps of V views, per channel.

    Args:
        center_maps: ``(V, C, H, W)`` heatmaps in [0, 1].
        Ks: ``(V, 3, 3)`` intrinsics. T_cam_world: ``(V, 4, 4)`` extrinsics (mm).
        config: see :class:`CenterConfig`.
        channel_obj_ids: object id per channel (None: one channel shared by all objects).
        known_counts: number of objects per channel when known (DIMO ``scene_info``, BOP targets);
            channels missing from it are not pruned by count.
        exclusive_channels: how ``config.class_agnostic`` joins the channels (:func:`class_agnostic_map`).

    Returns:
        Centres, best aggregated score first within each channel, channels in order.
    """
    center_maps = np.asarray(center_maps, dtype=np.float64)
    V, C = center_maps.shape[:2]
    if config.class_agnostic and C > 1:
        summed = class_agnostic_map(center_maps, exclusive_channels)
        total = None
        if known_counts is not None and all(c in known_counts for c in range(C)):
            total = {0: int(sum(known_counts[c] for c in range(C)))}
        found = detect_centers(summed, Ks, T_cam_world, replace(config, class_agnostic=False), None, total)
        return assign_channels(
            np.array([c.position for c in found]).reshape(-1, 3), center_maps, Ks, T_cam_world, channel_obj_ids,
            known_counts,
        )  # fmt: skip
    out: list[Center3D] = []
    for c in range(C):
        maps = center_maps[:, c]
        rays_o, rays_d, view, peaks = [], [], [], []
        for v in range(V):
            xy, _ = find_peaks(maps[v], config.peak_threshold, config.peak_min_distance)
            o, d = peak_rays(Ks[v], T_cam_world[v], xy)
            rays_o.append(o)
            rays_d.append(d)
            view.append(np.full(len(xy), v))
            peaks.append(xy)
        origins, directions, view_index = np.concatenate(rays_o), np.concatenate(rays_d), np.concatenate(view)
        candidates = triangulate_pairs(origins, directions, view_index, config.d_t)
        if len(candidates) == 0:
            continue
        merged = merge_candidates(candidates, sample_scores(candidates, maps, Ks, T_cam_world).sum(1), config.d_c)
        refined = refine_centers(merged, maps, Ks, T_cam_world, config)
        scores = sample_scores(refined, maps, Ks, T_cam_world)  # (Q, V)
        n = None if known_counts is None else known_counts.get(c)
        min_views = config.min_views if n is not None else max(config.min_views, config.min_views_unknown_count)
        keep = (scores >= config.min_view_score).sum(1) >= min_views
        keep &= _in_some_frustum(refined, Ks, T_cam_world, maps.shape[1:])
        refined, scores = refined[keep], scores[keep]
        chosen = select_centers(refined, scores, peaks, Ks, T_cam_world, config, min_views, n)
        refined, scores = refined[chosen], scores[chosen]
        obj_id = None if channel_obj_ids is None else int(channel_obj_ids[c])
        out.extend(Center3D(p, s, c, obj_id) for p, s in zip(refined, scores, strict=True))
    return out


def class_agnostic_map(center_maps: np.ndarray, exclusive: bool) -> np.ndarray:
    """``(V, 1, H, W)``: the probability that any object's centre is at a pixel, from the per-object channels of
    ``center_maps (V, C, H, W)`` in [0, 1].

    ``exclusive`` (the channels split one probability among the ids, as a factored network's do): their sum,
    clipped to [0, 1] for float rounding. Otherwise (each channel a probability of its own: the oracle's GT, a
    network with independent channels) their noisy-OR ``1 - prod(1 - p)``: the sum of such maps exceeds 1 where
    blobs of two ids overlap, and clipped it made flat plateaus that the peak finder returned as a grid of peaks,
    each a ray paired with every other view's; the noisy-OR is 1 at every GT centre and smooth between, and like the
    sum it adds up a network's evidence spread over look-alike ids. Measured on the oracle (2026-12-07, 2-core AMD
    EPYC): stage 2 of a T-LESS-layout run on seed 6161 12.3 s and 6.1 GB peak -> 0.4 s and 0.7 GB
    (``results/bench/run_tless_heatmaps-stage2_amd-epyc-2cores_2026-12-07.md``); BOP AR on four T-LESS-layout sets
    0.935 / 0.972 / 0.897 / 0.963 -> 0.945 / 0.972 / 0.887 / 0.963 (one part more placed on 4243, one fewer on 7272,
    where other centres led stage 3 elsewhere; the mean 0.942 either way; ``results/accuracy/README.md``)."""
    maps = np.asarray(center_maps, dtype=np.float64)
    if exclusive:
        return np.clip(maps.sum(1, keepdims=True), 0.0, 1.0)
    missed = np.ones((maps.shape[0], 1, *maps.shape[2:]))  # prod(1 - p), a channel at a time: no (V, C, H, W) copy
    for c in range(maps.shape[1]):
        missed *= 1.0 - np.clip(maps[:, c : c + 1], 0.0, 1.0)
    return 1.0 - missed


def assign_channels(
    points: np.ndarray,
    center_maps: np.ndarray,
    Ks: np.ndarray,
    T_cam_world: np.ndarray,
    channel_obj_ids: Sequence[int] | None,
    known_counts: Mapping[int, int] | None,
) -> list[Center3D]:
    """Each of ``points (Q, 3)`` (centres found on the summed map) as a centre of one channel of ``center_maps
    (V, C, H, W)``: greedily, the (point, channel) pair with the highest summed score over the views first, each
    point once, each channel at most its ``known_counts`` (absent: no limit). A point that scores 0 in every channel
    still open is dropped. Returns centres, best first within each channel, channels in order."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    C = center_maps.shape[1]
    if len(points) == 0:
        return []
    scores = np.stack([sample_scores(points, center_maps[:, c], Ks, T_cam_world) for c in range(C)], axis=1)  # Q, C, V
    total = scores.sum(-1)  # (Q, C)
    left = {c: (None if known_counts is None else known_counts.get(c)) for c in range(C)}
    chosen: dict[int, int] = {}
    for flat in np.argsort(-total, axis=None, kind="stable"):
        q, c = divmod(int(flat), C)
        if total[q, c] <= 0:
            break
        if q in chosen or left[c] == 0:
            continue
        chosen[q] = c
        if left[c] is not None:
            left[c] -= 1
    out = []
    for c in range(C):
        mine = sorted((q for q, cc in chosen.items() if cc == c), key=lambda q: -total[q, c])
        obj_id = None if channel_obj_ids is None else int(channel_obj_ids[c])
        out.extend(Center3D(points[q], scores[q, c], c, obj_id) for q in mine)
    return out


def _in_some_frustum(points: np.ndarray, Ks: np.ndarray, T_cam_world: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``(N,)`` True where a point projects inside at least one image, in front of its camera."""
    H, W = size
    p = np.einsum("vij,nj->vni", T_cam_world[:, :3, :3], points) + T_cam_world[:, None, :3, 3]
    z = p[..., 2]
    zs = np.where(z > 1e-6, z, 1.0)
    x = (Ks[:, None, 0, 0] * p[..., 0] + Ks[:, None, 0, 1] * p[..., 1]) / zs + Ks[:, None, 0, 2]
    y = Ks[:, None, 1, 1] * p[..., 1] / zs + Ks[:, None, 1, 2]
    inside = (z > 1e-6) & (x >= 0) & (x <= W) & (y >= 0) & (y <= H)
    return inside.any(0)


def project_points(points: np.ndarray, Ks: np.ndarray, T_cam_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Continuous image points ``(V, N, 2)`` of world ``points (N, 3)`` (pixel centres at ``u + 0.5``, as
    :func:`find_peaks`) and ``(V, N)`` True where a point is in front of the camera."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    p = np.einsum("vij,nj->vni", T_cam_world[:, :3, :3], points) + T_cam_world[:, None, :3, 3]
    z = p[..., 2]
    zs = np.where(z > 1e-6, z, 1.0)
    x = (Ks[:, None, 0, 0] * p[..., 0] + Ks[:, None, 0, 1] * p[..., 1]) / zs + Ks[:, None, 0, 2]
    y = Ks[:, None, 1, 1] * p[..., 1] / zs + Ks[:, None, 1, 2]
    return np.stack([x, y], axis=-1), z > 1e-6


def select_centers(
    points: np.ndarray,
    scores: np.ndarray,
    peaks: Sequence[np.ndarray],
    Ks: np.ndarray,
    T_cam_world: np.ndarray,
    config: CenterConfig,
    min_views: int,
    n: int | None = None,
) -> np.ndarray:
    """Indices of the centres kept among ``points (Q, 3)`` with per-view ``scores (Q, V)``, best summed
    score first, by peak ownership (module docstring, step 7).

    A point sits on a peak of view v when that view's nearest peak of ``peaks[v] (N_v, 2)`` lies within
    ``config.peak_match_px`` of its projection and the point scores at least ``config.min_view_score``
    there. A view counts for a point unless the point sits on a peak there that an accepted centre owns
    (that view's evidence is explained already). Greedily, the point with the best summed score over its
    counting views is accepted if at least ``min_views`` of them score ``min_view_score``, it sits on at
    least one peak nobody owns, and (with a known count ``n`` only) it lies ``config.d_o`` or more from
    every accepted centre; it then owns every peak it sits on. Stops after ``n`` centres when ``n`` is
    given.
    """
    Q, V = scores.shape
    if Q == 0 or n == 0:
        return np.zeros(0, dtype=np.int64)
    xy, front = project_points(points, Ks, T_cam_world)
    match = np.full((Q, V), -1, dtype=np.int64)  # the peak a point sits on, per view (-1: none)
    for v in range(V):
        if len(peaks[v]) == 0:
            continue
        dist = np.linalg.norm(xy[v][:, None] - peaks[v][None], axis=-1)  # (Q, N_v)
        nearest = dist.argmin(1)
        on_peak = front[v] & (dist[np.arange(Q), nearest] <= config.peak_match_px)
        on_peak &= scores[:, v] >= config.min_view_score
        match[on_peak, v] = nearest[on_peak]
    owned = [np.zeros(len(p), dtype=bool) for p in peaks]
    open_ = np.ones(Q, dtype=bool)
    total = scores.sum(1)
    kept: list[int] = []
    while open_.any() and (n is None or len(kept) < n):
        taken = np.zeros((Q, V), dtype=bool)  # sits on an owned peak
        for v in range(V):
            m = match[:, v] >= 0
            taken[m, v] = owned[v][match[m, v]]
        counting = ~taken
        free_peak = (match >= 0) & ~taken
        eligible = open_ & (((scores >= config.min_view_score) & counting).sum(1) >= min_views)
        eligible &= free_peak.any(1)
        if n is not None and kept:
            eligible &= np.linalg.norm(points[:, None] - points[kept][None], axis=-1).min(1) >= config.d_o
        if not eligible.any():
            break
        unexplained = np.where(eligible, (scores * counting).sum(1), -np.inf)
        best = int(np.lexsort((-total, -unexplained))[0])  # most unexplained score, then best total
        kept.append(best)
        open_[best] = False
        for v in np.flatnonzero(match[best] >= 0):
            owned[v][match[best, v]] = True
    kept_arr = np.asarray(kept, dtype=np.int64)
    return kept_arr[np.argsort(-total[kept_arr], kind="stable")]
