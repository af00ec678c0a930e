"""Stage 3 of CenDerNet (paper, Section 2.3): poses by render-and-compare of curvature, object by object.

For a scene: the predicted curvature heatmaps are binarised (at ``t_b``, or a network's calibrated threshold:
``PoseConfig.t_b_network``) and turned into distance maps
once (:func:`bop_cender.pose.cost.distance_maps`). Objects are then optimised one by one in order of
decreasing visibility (the aggregated center score of their 3D centre), each view weighted by the
object's center score in that view; the objects already placed are rendered into every view as a
depth buffer that hides the candidates behind them (so an object under another is fitted to what of it
is visible, the paper's reason for the order). Per object:

1. ``n_candidates`` poses: rotations uniform on SO(3), the model's centre normally distributed around
   the 3D centre (``translation_sigma_mm``), all costed in one batched call;
2. the best ``top_k`` refined by bounded Nelder-Mead (scipy) over a rotation-vector perturbation
   (bounded by ``rotation_bound_rad``) and the centre's position (a box of ``translation_bound_mm``
   around the 3D centre); the lowest final cost wins.

With ``search_cost="edges"`` (our default) steps 1 and 2 search on the edge-point proxy of the cost
(:mod:`bop_cender.pose.edge_cost`: 10-30x cheaper per pose, continuous in the pose), and the paper's
render cost then judges and polishes the finalists:

1. the candidates are ranked by a sparse edge model (``candidate_segments``), the best ``rerank`` again
   by the full edge model, and the best ``top_k`` of those refined by Nelder-Mead on the edge cost (with
   ``screen_starts``, ours on DIMO layouts: the best ``screen_starts`` refined briefly first, the ``top_k`` lowest
   of them, kept apart in rotation, refined on);
2. the refined poses are judged by the paper's render cost (or, with ``coverage_weight`` > 0, by the
   two-sided cost of :mod:`bop_cender.pose.coverage`: the render cost plus the target edges inside the
   pose's silhouette that it leaves unexplained), and the judged cost of the best is the object's final
   cost (the BOP score). Optionally (``polish_maxfev`` > 0, off by default since 2026-12-03) the best is
   polished first by a short Nelder-Mead on the render cost.

The paper places each object once. We sweep the objects twice more (``passes=3``, measured in
:class:`PoseConfig`): in the same order, each searched anew (its previous pose one more start) with every
other object as last placed as its occluder, where those hide other pixels of it than when it was fitted,
and of its refined finalists the one is kept with which the whole placement, all objects rendered
together, explains the target best, if better than before (``acceptance="finalists"``). An object placed early was fitted without the parts lying on it,
and its cost then charged it for their edges and for its own hidden contours; a wrong early pose also hid
the right one of a later object. ``--set poses.passes=1`` is the paper's single sweep.

Two more steps are ours (measured in :class:`PoseConfig`): a **centre term** in every cost above and in the
sweeps' judge (``center_weight``: how far the center heatmap at the pose's centre falls below its value at
the detected 3D centre; part of the final cost), and after the sweeps a **scene polish**
(``scene_polish_maxfev``, :mod:`bop_cender.pose.scene_polish`): each object refined on the scene cost in
windows around it, the others fixed, kept where the whole scene gains.

When a centre's object id is unknown (one center channel shared by several object types), both steps
run for every candidate id and the lowest final cost decides (the best random candidate alone picked
the wrong part in tests: a coarse candidate of a similar part can beat a slightly misaligned one).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import cached_property, partial

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from bop_cender.geometry.sampling import sample_scores
from bop_cender.pose.config import NelderMead, PoseConfig
from bop_cender.pose.cost import candidate_costs, distance_maps
from bop_cender.pose.coverage import scene_cost
from bop_cender.pose.edge_cost import EdgeModel, edge_costs, edge_model_of, edge_occluder
from bop_cender.pose.scene_polish import SceneWindow, scene_window
from bop_cender.render.candidate_curvature import occluded
from bop_cender.render.curvature import DEFAULT_CURVATURE_SCALE
from bop_cender.render.mesh import RenderMesh
from bop_cender.render.rasterizer import render_scene

#: Nelder-Mead works on rotation-vector perturbations scaled by this (mm per radian, about a part's
#: radius), so that one unit of either parameter moves a surface point by about a millimetre.
ROTATION_SCALE_MM = 50.0


@dataclass(frozen=True)
class PoseTarget:
    """What stage 3 fits one object to: its 3D centre, per-view scores, the object ids it may be and, for
    ``PoseConfig.center_weight``, the center heatmaps ``(V, H, W)`` it was found in (None: no centre term)."""

    center: np.ndarray
    view_scores: np.ndarray
    obj_ids: tuple[int, ...]
    center_map: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class PlacedObject:
    """One optimised object: ``T_world_model (4, 4)``, its final cost (pixels) and the evaluations it took."""

    obj_id: int
    T_world_model: np.ndarray
    cost: float
    evaluations: int


@dataclass
class SceneCameras:
    """The scene's cameras as the cost needs them: ``Ks (V, 3, 3)``, ``T_cam_world (V, 4, 4)``, image size."""

    Ks: np.ndarray
    T_cam_world: np.ndarray
    height: int
    width: int

    def downscaled(self, factor: int) -> SceneCameras:
        """The same cameras with images ``factor`` times smaller: continuous image points divide by ``factor``
        (so pixel centres stay at ``u + 0.5``), image size rounded up."""
        K = self.Ks.copy()
        K[:, :2] /= factor
        return SceneCameras(K, self.T_cam_world, -(-self.height // factor), -(-self.width // factor))


@dataclass
class CostMaps:
    """Distance maps ``(V, H, W)`` of one resolution, the cameras that go with them and, at full
    resolution, the binarised target curvature ``edges (V, H, W)`` they were made from."""

    cameras: SceneCameras
    dist: torch.Tensor
    edges: torch.Tensor | None = None


def optimise_scene(
    targets: Sequence[PoseTarget],
    curvature: torch.Tensor | np.ndarray,
    cameras: SceneCameras,
    meshes: Callable[[int], RenderMesh],
    model_centers: Callable[[int], np.ndarray],
    config: PoseConfig,
    progress: Callable[[int, int], None] | None = None,
    cost_threads: int = 1,
    edges: Callable[[int], EdgeModel] | None = None,
    curvature_scale: float = DEFAULT_CURVATURE_SCALE,
    target_threshold: float | None = None,
    device: torch.device | str | None = None,
) -> list[PlacedObject]:
    """Poses of all ``targets``, most visible first, each occluded by those placed before it.

    Args:
        targets: one per detected object.
        curvature: ``(V, H, W)`` predicted curvature in [0, 1].
        cameras: the views.
        meshes: the renderer's mesh of an object id.
        model_centers: the 3D centre ``(3,)`` of an object id in model coordinates (bbox centre).
        config: see :class:`PoseConfig`.
        progress: called with (objects done, objects) after each object.
        cost_threads: threads that render the chunks of the candidate batch side by side
            (:func:`~bop_cender.pose.cost.candidate_costs` ``workers``: the same bits; worth it with one
            torch thread and free cores: 258 against 169 calls/s on 2 cores, ``results/bench/run_*``).
        edges: the edge model of an object id, on ``device`` (default: built from ``meshes`` on first use).
        curvature_scale: the targets' curvature scale ``c`` (``curvature`` is ``clip(raw / c, 0, 1)``):
            the two-sided judge binarises a pose's raw curvature at ``t_b * c``, as a GT target is.
        target_threshold: binarise ``curvature`` here instead of at ``config.t_b`` (a network's curvature:
            :attr:`~bop_cender.net.heatmaps.Heatmaps.curvature_threshold`); None: ``t_b``.
        device: where every render and cost runs (None: the device of ``curvature``, CPU for an array).
            The distance transform runs on the CPU (SciPy), once per scene; its maps, the meshes and the
            edge models then live on ``device`` (``cost_threads`` only counts on the CPU).

    Returns:
        One :class:`PlacedObject` per target, in the order they were placed.
    """
    if device is None:
        device = curvature.device if isinstance(curvature, torch.Tensor) else torch.device("cpu")
    device = torch.device(device)
    meshes = _MeshesOn(meshes, device)
    if edges is None:
        edges = _EdgeModels(meshes, config.edge_segment_mm)
    curv = torch.as_tensor(curvature).detach().to("cpu", torch.float32)
    binary = curv > (config.t_b if target_threshold is None else target_threshold)
    fine = CostMaps(cameras, torch.as_tensor(distance_maps(binary.numpy())).to(device), binary.to(device))
    f = max(1, int(config.candidates.downscale))
    coarse = fine
    if f > 1 and config.search_cost == "render":  # the edge search costs everything on the fine maps
        pooled = torch.nn.functional.max_pool2d(binary[:, None].float(), f, ceil_mode=True)[:, 0] > 0
        coarse = CostMaps(cameras.downscaled(f), torch.as_tensor(distance_maps(pooled.numpy())).to(device))
    order = sorted(range(len(targets)), key=lambda i: -float(np.sum(targets[i].view_scores)))
    total = len(targets) * config.sweeps.passes
    edge_threshold = config.t_b * curvature_scale

    def fit(
        i: int,
        others: list[PlacedObject],
        occ: torch.Tensor | None,
        sweep: int,
        incumbent: PlacedObject | None,
        finalists: list[PlacedObject] | None = None,
    ) -> PlacedObject:
        occ_coarse = occ
        if occ is not None and coarse is not fine:
            occ_coarse = _occluder_depth(others, coarse.cameras, meshes)
        rng = np.random.default_rng([config.seed, i] if sweep == 0 else [config.seed, i, sweep])
        return optimise_object(
            targets[i], (coarse, occ_coarse), (fine, occ), meshes, model_centers, config, rng, cost_threads, edges,
            edge_threshold, incumbent=incumbent, finalists=finalists,
        )  # fmt: skip

    placed: list[PlacedObject] = []
    contexts: list[torch.Tensor | None] = []  # the occluder depth each object was last fitted under
    for n, i in enumerate(order):
        occ = _occluder_depth(placed, fine.cameras, meshes) if config.occlusion and placed else None
        placed.append(fit(i, placed, occ, 0, None))
        contexts.append(occ)
        if progress is not None:
            progress(n + 1, total)
    scene_now: float | None = None  # the scene cost of ``placed`` (acceptance scene or finalists), once computed

    # the target of placed[k] is targets[order[k]]
    judge = SceneJudge([targets[i] for i in order], fine, meshes, model_centers, config, edge_threshold)

    for sweep in range(1, config.sweeps.passes):
        for idx, i in enumerate(order):
            others = placed[:idx] + placed[idx + 1 :]
            occ = _occluder_depth(others, fine.cameras, meshes) if config.occlusion and others else None
            # where nothing hides it differently from when it was fitted, the same search would be repeated
            if _hidden_pixels_differ(placed[idx], contexts[idx], occ, fine.cameras, meshes):
                pool: list[PlacedObject] = []
                moved = fit(i, others, occ, sweep, placed[idx], pool)
                if scene_now is None:
                    scene_now = judge.cost(placed)
                moved, scene_now = _choose_by_scene(placed, idx, moved, pool, scene_now, judge.cost)
                placed[idx] = moved
                contexts[idx] = occ  # searched under these occluders, kept or not: a third sweep skips alike
            if progress is not None:
                progress(sweep * len(targets) + idx + 1, total)
    if config.scene_polish.nelder_mead.maxfev > 0 and placed:
        for polish_pass in range(config.scene_polish.passes):
            before = [p.T_world_model for p in placed]
            placed = polish_on_scene(placed, judge, scene_now if polish_pass == 0 else None)
            if all(np.array_equal(p.T_world_model, T) for p, T in zip(placed, before, strict=True)):
                break  # nothing moved: another pass would repeat this one
    return placed


def polish_on_scene(
    placed: list[PlacedObject], judge: SceneJudge, scene_now: float | None = None
) -> list[PlacedObject]:
    """Each of ``placed`` (in order; ``judge.targets[i]`` is the target of ``placed[i]``) refined on the scene cost
    in windows around it, the others fixed (:mod:`bop_cender.pose.scene_polish`): Nelder-Mead from a simplex a
    quarter of ``nm_initial_*``, at most ``scene_polish_maxfev`` evaluations (tolerances ``scene_polish_xatol``,
    ``scene_polish_fatol``), within the search's bounds about the
    object's 3D centre. The polished pose replaces the old where ``judge.cost`` (the full scene cost plus the
    centre terms) falls; its final cost is then its judged cost under all the others (render or two-sided,
    plus its centre term, as a sweep's). ``scene_now``: ``judge.cost(placed)`` where known. Returns the new
    placement."""
    placed = list(placed)
    if not placed:
        return placed
    maps, meshes, config = judge.maps, judge.meshes, judge.config
    if scene_now is None:
        scene_now = judge.cost(placed)
    for idx, obj in enumerate(placed):
        others = placed[:idx] + placed[idx + 1 :]
        window = scene_window(
            meshes(obj.obj_id), obj.T_world_model, [(meshes(o.obj_id), o.T_world_model) for o in others],
            maps.cameras.Ks, maps.cameras.T_cam_world, maps.edges, maps.dist, judge.edge_threshold,
            config.scene_polish.margin_px,
        )  # fmt: skip
        # the occluders only matter for the final cost of a kept pose: rendered then, not for every part
        problem = _refinement(judge.targets[idx], obj.obj_id, maps, None, meshes, judge.model_centers, config,
                              judge.edge_threshold)  # fmt: skip
        T_new, _, fev = _refine_lockstep(
            obj.T_world_model[None], problem, partial(_polish_cost, window, problem), config.scene_polish.nelder_mead
        )
        trial = _with(placed, idx, replace(obj, T_world_model=T_new[0]))
        cost = judge.cost(trial)
        spent = obj.evaluations + fev + 1
        if cost < scene_now:
            if config.occlusion and others:
                problem = replace(problem, occluder_depth=_occluder_depth(others, maps.cameras, meshes))
            final = problem.cost(T_new) + problem.center_term(T_new)
            placed[idx] = PlacedObject(obj.obj_id, T_new[0], float(final[0]), spent + 1)
            scene_now = cost
        else:
            placed[idx] = replace(obj, evaluations=spent)
    return placed


def _choose_by_scene(
    placed: list[PlacedObject],
    idx: int,
    moved: PlacedObject,
    pool: list[PlacedObject],
    scene_now: float,
    scene: Callable[[list[PlacedObject]], float],
) -> tuple[PlacedObject, float]:
    """A further sweep's choice for object ``idx``: of its current pose and the new search's refined finalists
    ``pool`` (its best ``moved`` where the pool is empty), the one whose placement has the lowest scene cost
    (``scene``); ties keep the current pose.

    Returns the chosen object (its evaluations: all the new search spent) and the scene cost."""
    best, best_cost, spent = placed[idx], scene_now, moved.evaluations
    for option in pool or [moved]:
        cost = scene(_with(placed, idx, option))
        if cost < best_cost:
            best, best_cost = option, cost
    return replace(best, evaluations=spent), best_cost


def _with(placed: list[PlacedObject], idx: int, obj: PlacedObject) -> list[PlacedObject]:
    """``placed`` with its ``idx``-th object replaced by ``obj`` (a trial placement)."""
    return placed[:idx] + [obj] + placed[idx + 1 :]


def view_weights(view_scores: np.ndarray) -> np.ndarray:
    """``(V,)`` weights summing to 1: the per-view center scores (the paper's), equal where they sum to 0."""
    s = np.clip(np.asarray(view_scores, dtype=np.float64), 0.0, None)
    if s.sum() <= 0:
        return np.full(len(s), 1.0 / len(s))
    return s / s.sum()


def optimise_object(
    target: PoseTarget,
    coarse: tuple[CostMaps, torch.Tensor | None],
    fine: tuple[CostMaps, torch.Tensor | None],
    meshes: Callable[[int], RenderMesh],
    model_centers: Callable[[int], np.ndarray],
    config: PoseConfig,
    rng: np.random.Generator,
    cost_threads: int = 1,
    edges: Callable[[int], EdgeModel] | None = None,
    edge_threshold: float | None = None,
    incumbent: PlacedObject | None = None,
    finalists: list[PlacedObject] | None = None,
) -> PlacedObject:
    """Random candidates then bounded Nelder-Mead for one object (see the module docstring).

    ``coarse`` (maps and occluder depth at ``candidate_downscale``) costs the candidates of the render
    search; ``fine`` (full resolution) everything else. ``edges``: the edge model of an object id
    (``search_cost="edges"``; None: built here). ``edge_threshold``: raw curvature of a pose's own edges
    for the two-sided judge (:mod:`bop_cender.pose.coverage`; needed with ``coverage_weight`` > 0). ``incumbent``: the object's pose from an
    earlier sweep, refined as one more start (its evaluations are added to the result's). ``finalists``: where
    given, every refined pose of every candidate id is appended to it (final cost each, 0 evaluations), so
    that a caller can judge them otherwise (``acceptance="finalists"``)."""
    n = config.candidates.n
    R = Rotation.random(n, random_state=rng).as_matrix()
    centers = target.center[None] + rng.normal(0.0, config.candidates.translation_sigma_mm, size=(n, 3))
    best: PlacedObject | None = None
    evaluations = 0 if incumbent is None else incumbent.evaluations
    maps, occ = fine
    for obj_id in target.obj_ids:
        mesh, center_model = meshes(obj_id), model_centers(obj_id)
        T = _poses(R, centers, center_model)
        extra = incumbent.T_world_model[None] if incumbent is not None and incumbent.obj_id == obj_id else None
        problem = _refinement(target, obj_id, maps, occ, meshes, model_centers, config, edge_threshold)
        if config.search_cost == "edges":
            model = edges(obj_id) if edges is not None else edge_model_of(mesh, config.edge_segment_mm)
            T_ref, c_ref, fev = _search_on_edges(T, model, problem, extra)
        else:
            costs = _cost(mesh, T, coarse[0].cameras, coarse[0].dist, problem.weights, coarse[1], cost_threads)
            starts = T[np.argsort(costs, kind="stable")[: max(1, config.candidates.top_k)]]
            starts = starts if extra is None else np.concatenate([starts, extra])
            T_ref, c_ref, fev = _refine_lockstep(starts, problem)
            fev += n
        evaluations += fev
        if finalists is not None:
            finalists += [PlacedObject(obj_id, T_ref[j], float(c_ref[j]), 0) for j in range(len(T_ref))]
        k = int(np.argmin(c_ref))
        if best is None or c_ref[k] < best.cost:
            best = PlacedObject(obj_id, T_ref[k], float(c_ref[k]), 0)
    assert best is not None
    return PlacedObject(best.obj_id, best.T_world_model, best.cost, evaluations)


def _search_on_edges(
    T: np.ndarray, model: EdgeModel, problem: Refinement, extra: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, int]:
    """Candidates ``T (n, 4, 4)`` ranked and refined on the edge cost, the finalists judged (two-sided cost,
    or the render cost with ``coverage_weight`` 0) and, with ``polish_maxfev`` > 0, the best polished on the
    render cost. ``extra (e, 4, 4)``: poses refined as starts beside the best candidates (an earlier sweep's
    pose). Returns the finalists' poses ``(k, 4, 4)``, their final costs ``(k,)`` and the evaluations."""
    config, cand = problem.config, problem.config.candidates
    sparse = model.sparse(cand.segments)
    coarse_costs = problem.search_cost(T, sparse)
    pool = np.argsort(coarse_costs, kind="stable")[: max(1, cand.rerank, cand.top_k, config.screen.starts)]
    pool = pool[np.argsort(problem.search_cost(T[pool], model), kind="stable")]
    search_cost = partial(problem.search_cost, model=model)
    evaluations = len(T) + len(pool)
    if min(config.screen.starts, len(pool)) > max(1, cand.top_k):
        # a short Nelder-Mead from more starts first; the best top_k after it go on (a start 10-20 degrees from
        # the true pose costs more than a wrong basin's best candidate, and only refining shows which is which);
        # those that go on are kept apart in rotation again (screened starts often meet in one basin)
        screened = T[pool[_diverse(T[pool], config.screen.starts, cand.start_separation_rad)]]
        T_s, f_s, fev = _refine_lockstep(screened, problem, search_cost, config.screen.nelder_mead)
        ranked = T_s[np.argsort(f_s, kind="stable")]
        starts = ranked[_diverse(ranked, max(1, cand.top_k), cand.start_separation_rad)]
        evaluations += fev
    else:
        starts = T[pool[_diverse(T[pool], max(1, cand.top_k), cand.start_separation_rad)]]
    if extra is not None:
        starts = np.concatenate([starts, extra])
    T_ref, _, fev = _refine_lockstep(starts, problem, search_cost)
    evaluations += fev
    final = problem.cost(T_ref) + problem.center_term(T_ref)
    evaluations += len(T_ref)
    return T_ref, final, evaluations


def _polish_cost(window: SceneWindow, problem: Refinement, T_world_model: np.ndarray) -> np.ndarray:
    """``(n,)`` what the scene polish minimises for poses ``(n, 4, 4)``: the windowed scene cost plus the centre term."""
    return window.costs(T_world_model) + problem.center_term(T_world_model)


def _refinement(
    target: PoseTarget,
    obj_id: int,
    maps: CostMaps,
    occluder_depth: torch.Tensor | None,
    meshes: Callable[[int], RenderMesh],
    model_centers: Callable[[int], np.ndarray],
    config: PoseConfig,
    edge_threshold: float | None,
) -> Refinement:
    """What object ``obj_id`` at ``target`` is refined against: ``maps`` (full resolution) under the occluders."""
    weights = torch.as_tensor(view_weights(target.view_scores), dtype=torch.float32, device=maps.dist.device)
    return Refinement(
        target.center, model_centers(obj_id), meshes(obj_id), maps.cameras, maps.dist, weights, occluder_depth,
        config, maps.edges, edge_threshold, np.asarray(target.view_scores, dtype=np.float64), target.center_map,
    )  # fmt: skip


def _diverse(T: np.ndarray, k: int, separation_rad: float) -> np.ndarray:
    """Indices of up to ``k`` of the poses ``T (n, 4, 4)`` (best first): greedily, each one whose rotation
    differs from every pose taken before by more than ``separation_rad`` (0: the first k), topped up in
    order when too few differ."""
    if separation_rad <= 0 or len(T) <= 1:
        return np.arange(min(k, len(T)))
    R = T[:, :3, :3]
    taken = [0]
    for i in range(1, len(T)):
        if len(taken) == k:
            break
        cos = (np.einsum("kij,ij->k", R[taken], R[i]) - 1.0) / 2.0  # cos of the angle between rotations
        if np.all(cos < np.cos(separation_rad)):
            taken.append(i)
    rest = [i for i in range(len(T)) if i not in taken][: k - len(taken)]
    return np.array(taken + rest)


class _MeshesOn:
    """The render meshes of object ids on the pose stage's ``device``, each moved there once."""

    def __init__(self, meshes: Callable[[int], RenderMesh], device: torch.device) -> None:
        self.meshes, self.device, self.cache = meshes, device, {}

    def __call__(self, obj_id: int) -> RenderMesh:
        if obj_id not in self.cache:
            mesh = self.meshes(obj_id)
            self.cache[obj_id] = mesh if mesh.device == self.device else mesh.to(self.device)
        return self.cache[obj_id]


class _EdgeModels:
    """Edge models of object ids, built from their render meshes on first use."""

    def __init__(self, meshes: Callable[[int], RenderMesh], segment_mm: float) -> None:
        self.meshes, self.segment_mm, self.cache = meshes, segment_mm, {}

    def __call__(self, obj_id: int) -> EdgeModel:
        if obj_id not in self.cache:
            self.cache[obj_id] = edge_model_of(self.meshes(obj_id), self.segment_mm)
        return self.cache[obj_id]


def _poses(R: np.ndarray, centers_world: np.ndarray, center_model: np.ndarray) -> np.ndarray:
    """``T_world_model (n, 4, 4)`` with rotation ``R (n, 3, 3)`` whose model centre lands on ``centers_world (n, 3)``."""
    n = len(R)
    T = np.zeros((n, 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = centers_world - R @ center_model
    T[:, 3, 3] = 1.0
    return T


def _cost(
    mesh: RenderMesh,
    T_world_model: np.ndarray,
    cameras: SceneCameras,
    dist: torch.Tensor,
    weights: torch.Tensor,
    occluder_depth: torch.Tensor | None,
    threads: int = 1,
) -> np.ndarray:
    """``(n,)`` float64 costs of ``T_world_model (n, 4, 4)`` in all views (``threads``: chunk threads)."""
    T_cm = np.einsum("vij,njk->nvik", cameras.T_cam_world, T_world_model)
    out = candidate_costs(
        mesh,
        torch.as_tensor(T_cm, dtype=torch.float32, device=dist.device),
        torch.as_tensor(cameras.Ks, dtype=torch.float32, device=dist.device),
        cameras.height,
        cameras.width,
        dist,
        weights,
        occluder_depth=occluder_depth,
        workers=threads,
    )
    return out.double().cpu().numpy()


@dataclass(frozen=True)
class Refinement:
    """What the Nelder-Mead refinement of one object fits to: its 3D centre, model, the full-resolution
    distance maps and cameras, view weights, the placed objects' depth and the settings."""

    center3d: np.ndarray
    center_model: np.ndarray
    mesh: RenderMesh
    cameras: SceneCameras
    dist: torch.Tensor
    weights: torch.Tensor
    occluder_depth: torch.Tensor | None
    config: PoseConfig
    target_edges: torch.Tensor | None = None
    edge_threshold: float | None = None
    view_scores: np.ndarray | None = None
    center_map: np.ndarray | None = None

    def center_term(self, T_world_model: np.ndarray) -> np.ndarray:
        """``(n,)`` :func:`center_term` of poses ``(n, 4, 4)`` of this object."""
        return center_term(T_world_model, self.center_model, self.view_scores, self.center_map, self._weights_np,
                           self.cameras, self.config.center_weight)  # fmt: skip

    @cached_property
    def _weights_np(self) -> np.ndarray:
        """``weights`` as float64 NumPy ``(V,)``, once (the centre term reads them at every evaluation)."""
        return self.weights.detach().cpu().double().numpy()

    @cached_property
    def edge_occluder(self) -> torch.Tensor | None:
        """The occluder depth widened for the edge cost (:func:`~bop_cender.pose.edge_cost.edge_occluder`)."""
        return None if self.occluder_depth is None else edge_occluder(self.occluder_depth)

    def cost(self, T_world_model: np.ndarray) -> np.ndarray:
        """``(n,)`` render costs of poses ``(n, 4, 4)``."""
        return _cost(self.mesh, T_world_model, self.cameras, self.dist, self.weights, self.occluder_depth)

    def search_cost(self, T_world_model: np.ndarray, model: EdgeModel) -> np.ndarray:
        """``(n,)`` what the edge search ranks and refines poses ``(n, 4, 4)`` by: the edge cost plus the centre term."""
        return self.edge_cost(T_world_model, model) + self.center_term(T_world_model)

    def edge_cost(self, T_world_model: np.ndarray, model: EdgeModel) -> np.ndarray:
        """``(n,)`` edge-point costs (:func:`~bop_cender.pose.edge_cost.edge_costs`) of poses ``(n, 4, 4)``."""
        T_cm = np.einsum("vij,njk->nvik", self.cameras.T_cam_world, T_world_model)
        out = edge_costs(
            model,
            torch.as_tensor(T_cm, dtype=torch.float32, device=self.dist.device),
            torch.as_tensor(self.cameras.Ks, dtype=torch.float32, device=self.dist.device),
            self.dist,
            self.weights,
            self.edge_occluder,
        )
        return out.double().cpu().numpy()


@dataclass(frozen=True)
class _Perturbation:
    """Nelder-Mead's parameters ``x = (rotvec * ROTATION_SCALE_MM, centre - center3d)`` around start rotations."""

    R0: np.ndarray  # (k, 3, 3)
    center3d: np.ndarray  # (3,)
    center_model: np.ndarray  # (3,)

    def poses(self, x: np.ndarray, start: np.ndarray) -> np.ndarray:
        """``T_world_model (m, 4, 4)`` of parameters ``x (m, 6)`` applied to starts ``start (m,)``."""
        R = Rotation.from_rotvec(x[:, :3] / ROTATION_SCALE_MM).as_matrix() @ self.R0[start]
        return _poses(R, self.center3d[None] + x[:, 3:], self.center_model)


def _bounds_and_starts(
    starts: np.ndarray, center3d: np.ndarray, center_model: np.ndarray, config: PoseConfig, nelder_mead: NelderMead
):
    rb = config.refine.rotation_bound_rad * ROTATION_SCALE_MM
    tb = config.refine.translation_bound_mm
    lo = np.concatenate([np.full(3, -rb), np.full(3, -tb)])
    c0 = np.einsum("kij,j->ki", starts[:, :3, :3], center_model) + starts[:, :3, 3]
    x0 = np.concatenate([np.zeros((len(starts), 3)), np.clip(c0 - center3d, -tb, tb)], axis=1)
    step = np.concatenate(
        [
            np.full(3, nelder_mead.initial_rotation_rad * ROTATION_SCALE_MM),
            np.full(3, nelder_mead.initial_translation_mm),
        ]
    )
    return x0, step, lo, -lo


def _refine_lockstep(
    starts: np.ndarray,
    problem: Refinement,
    cost: Callable[[np.ndarray], np.ndarray] | None = None,
    nelder_mead: NelderMead | None = None,
) -> tuple[np.ndarray, np.ndarray, int]:
    """All starts ``(k, 4, 4)`` refined together (:func:`bop_cender.optim.simplex.batched_nelder_mead`) on
    ``cost`` (poses ``(m, 4, 4)`` -> ``(m,)``; default the render cost, ``problem.cost``).

    Returns the refined poses ``(k, 4, 4)``, their costs ``(k,)`` and the evaluations spent."""
    cost = problem.cost if cost is None else cost
    from bop_cender.optim.simplex import batched_nelder_mead

    config = problem.config
    nm = config.refine.nelder_mead if nelder_mead is None else nelder_mead
    x0, step, lo, hi = _bounds_and_starts(starts, problem.center3d, problem.center_model, config, nm)
    param = _Perturbation(starts[:, :3, :3], problem.center3d, problem.center_model)
    k = len(starts)
    # Each point carries the index of its start as a 7th coordinate that never moves (step 0, bounds
    # [0, k - 1]; every simplex vertex and reflection of start i keeps the value i).
    x0 = np.concatenate([x0, np.arange(k, dtype=np.float64)[:, None]], axis=1)
    step, lo, hi = np.append(step, 0.0), np.append(lo, 0.0), np.append(hi, float(k - 1))

    def f(x: np.ndarray) -> np.ndarray:
        owner = np.rint(x[:, -1]).astype(np.int64)
        return cost(param.poses(x[:, :-1], owner))

    x_best, f_best, nfev = batched_nelder_mead(f, x0, step, lo, hi, nm.xatol, nm.fatol, nm.maxfev)
    return param.poses(x_best[:, :-1], np.arange(k)), f_best, int(nfev.sum())


def _hidden_pixels_differ(
    obj: PlacedObject,
    before: torch.Tensor | None,
    after: torch.Tensor | None,
    cameras: SceneCameras,
    meshes: Callable[[int], RenderMesh],
) -> bool:
    """Whether the occluder depth ``after (V, H, W)`` hides other pixels of ``obj`` than ``before`` did
    (the render cost's rule; None: no occluder). Where it hides the same ones, the object's cost and its
    search see the same image, and a later sweep keeps its pose."""
    if before is None and after is None:
        return False
    T_cm = np.einsum("vij,jk->vik", cameras.T_cam_world, obj.T_world_model)[:, None]
    mesh = meshes(obj.obj_id)
    depth = render_scene(
        [mesh],
        torch.as_tensor(T_cm, dtype=torch.float32, device=mesh.device),
        torch.as_tensor(cameras.Ks, dtype=torch.float32, device=mesh.device),
        cameras.height,
        cameras.width,
    ).depth

    def hidden(occ: torch.Tensor | None) -> torch.Tensor:
        return torch.zeros_like(depth, dtype=torch.bool) if occ is None else occluded(depth, occ)

    return not torch.equal(hidden(before), hidden(after))


def _scene_cost(
    placed: Sequence[PlacedObject], maps: CostMaps, meshes: Callable[[int], RenderMesh], edge_threshold: float
) -> float:
    """:func:`~bop_cender.pose.coverage.scene_cost` of ``placed`` against the full-resolution ``maps``."""
    T_wm = np.stack([p.T_world_model for p in placed])
    T_cm = np.einsum("vij,mjk->vmik", maps.cameras.T_cam_world, T_wm)
    return scene_cost(
        [meshes(p.obj_id) for p in placed],
        torch.as_tensor(T_cm, dtype=torch.float32, device=maps.dist.device),
        torch.as_tensor(maps.cameras.Ks, dtype=torch.float32, device=maps.dist.device),
        maps.edges,
        maps.dist,
        edge_threshold,
    )


def center_term(
    T_world_model: np.ndarray,
    center_model: np.ndarray,
    view_scores: np.ndarray | None,
    center_map: np.ndarray | None,
    weights: np.ndarray,
    cameras: SceneCameras,
    center_weight: float,
) -> np.ndarray:
    """``(n,)`` the centre term of poses ``(n, 4, 4)`` of one object (pixels; ours, ``PoseConfig.center_weight``).

    ``center_weight`` times the ``weights (V,)``-weighted mean over the views of how far the center heatmap
    ``center_map (V, H, W)`` at the projection of the pose's centre (``center_model`` in model coordinates)
    falls below its value at the detected 3D centre (``view_scores (V,)``): 0 at the detected centre, at
    most ``center_weight``. Sharp heatmaps (the oracle's) hold a pose at its centre; smeared ones (a
    network's, whose centres are less sure) let it move further for the same cost. 0 where there is no
    centre map or the weight is 0."""
    n = len(T_world_model)
    if center_weight <= 0 or center_map is None or view_scores is None:
        return np.zeros(n)
    centers = np.einsum("nij,j->ni", T_world_model[:, :3, :3], center_model) + T_world_model[:, :3, 3]
    values = sample_scores(centers, center_map, cameras.Ks, cameras.T_cam_world)  # (n, V)
    drop = np.clip(np.asarray(view_scores, dtype=np.float64)[None] - values, 0.0, None)
    return center_weight * (drop * weights).sum(1) / max(float(weights.sum()), 1e-12)


@dataclass(frozen=True)
class SceneJudge:
    """What a whole placement is judged against: the targets in placement order (``targets[k]`` is that of
    ``placed[k]``), the full-resolution ``maps`` (with their binarised ``edges``), the meshes and model centres
    of the object ids, the settings and the raw curvature of a pose's own edges (``edge_threshold``)."""

    targets: Sequence[PoseTarget]
    maps: CostMaps
    meshes: Callable[[int], RenderMesh]
    model_centers: Callable[[int], np.ndarray]
    config: PoseConfig
    edge_threshold: float

    def cost(self, placed: Sequence[PlacedObject]) -> float:
        """What the sweeps and the scene polish judge ``placed`` by: its scene cost (:func:`_scene_cost`) plus,
        with ``center_weight`` > 0, each object's :func:`center_term`."""
        cost = _scene_cost(placed, self.maps, self.meshes, self.edge_threshold)
        if self.config.center_weight > 0:
            for obj, target in zip(placed, self.targets, strict=True):
                w = view_weights(target.view_scores)
                cost += float(center_term(obj.T_world_model[None], self.model_centers(obj.obj_id), target.view_scores,
                                          target.center_map, w, self.maps.cameras, self.config.center_weight)[0])  # fmt: skip
        return cost


def _occluder_depth(
    placed: Sequence[PlacedObject], cameras: SceneCameras, meshes: Callable[[int], RenderMesh]
) -> torch.Tensor:
    """``(V, H, W)`` depth of the placed objects rendered together in every view (0: nothing)."""
    T_wm = np.stack([p.T_world_model for p in placed])
    T_cm = np.einsum("vij,mjk->vmik", cameras.T_cam_world, T_wm)
    placed_meshes = [meshes(p.obj_id) for p in placed]
    device = placed_meshes[0].device
    render = render_scene(
        placed_meshes,
        torch.as_tensor(T_cm, dtype=torch.float32, device=device),
        torch.as_tensor(cameras.Ks, dtype=torch.float32, device=device),
        cameras.height,
        cameras.width,
    )
    return render.depth
