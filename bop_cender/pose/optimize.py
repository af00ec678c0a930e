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
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation

from bop_cender.errors import ConfigError
from bop_cender.geometry.sampling import sample_scores
from bop_cender.pose.backend import Backend, backend_named
from bop_cender.pose.cost import distance_maps
from bop_cender.pose.coverage import TwoSidedCost, two_sided_costs
from bop_cender.pose.edge_cost import edge_occluder
from bop_cender.pose.edge_model import EdgeModel, edge_model_of
from bop_cender.pose.scene_polish import SceneWindow, scene_window
from bop_cender.render.backend import BACKEND_NAMES
from bop_cender.render.candidate_curvature import occluded
from bop_cender.render.curvature import DEFAULT_CURVATURE_SCALE
from bop_cender.render.mesh import RenderMesh
from bop_cender.render.rasterizer import render_scene
from bop_cender.settings_checks import COUNT, COUNT_OR_ZERO, NON_NEGATIVE, POSITIVE, Bound, check_settings

#: Nelder-Mead works on rotation-vector perturbations scaled by this (mm per radian, about a part's
#: radius), so that one unit of either parameter moves a surface point by about a millimetre.
ROTATION_SCALE_MM = 50.0


SEARCH_COSTS = ("edges", "render")
REFINERS = ("lockstep", "scipy")
VIEW_WEIGHTS = ("center", "uniform")
ACCEPTANCES = ("object", "scene", "finalists")


@dataclass(frozen=True)
class PoseConfig:
    """Stage-3 settings. The paper gives 2,000 candidates and bounded Nelder-Mead; every other value is ours.

    Attributes:
        t_b: binarisation threshold of the predicted curvature (in [0, 1]); ours: 0.75, with the
            targets' scale c = 4 a raw curvature of 3: silhouettes and sharp creases (3 to 4.2) pass,
            the curved surfaces of thin parts (1.3 to 2.9) do not (see ``TargetConfig.curvature_scale``).
        t_b_network: binarisation threshold of a network's predicted curvature (the target side only: a rendered
            pose's edges stay those above ``t_b``, the edges the network was trained to predict). None (ours): the
            threshold calibrated for the weights (:attr:`~bop_cender.net.weights.NetWeights.curvature_threshold`:
            the best-F1 threshold on their validation views), or ``t_b`` for weights without one. Why: a network's
            curvature is softer than the renderer's; at ``t_b`` its edges break up (shipped DIMO network, seed
            9002 ``sim``: curvature F1 0.444 at 0.75, 0.622 at 0.62), and the pose stage then fits fragments.
            Measured end to end with the shipped weights' calibrations (DIMO 0.629, T-LESS 0.424, from their
            validation sets; ``results/accuracy/README.md``, fifth session): AR_MSSD<5% DIMO seed 9002 ``sim``
            0.682 -> 0.777, ``real`` 0.252 -> 0.640, seed 4242 ``sim`` 0.447 -> 0.576; T-LESS seed 4243 AR
            0.355 -> 0.486. A fixed threshold for both sides (``t_b`` 0.4 / 0.5 / 0.6) gave 0.797 / 0.792 / 0.786
            on 9002 ``sim``: a plateau that the calibrated value sits on.
        n_candidates: random pose candidates per object (paper: 2,000).
        translation_sigma_mm: standard deviation of the candidates' centre around the 3D centre (ours:
            5 mm, the triangulation error of stage 2 is a few mm on oracle heatmaps).
        top_k: candidates refined by Nelder-Mead (ours: 3; with ``screen_starts``, the 3 best of the screened starts).
        rotation_bound_rad: bound on each rotation-vector component of the refinement's perturbation
            (ours: 0.6 rad, about the spacing of 2,000 random rotations (~0.35 rad) plus margin).
        translation_bound_mm: the refined centre stays within this box around the 3D centre (ours: 20 mm).
        translation_sigma_mm_network, translation_bound_mm_network: the two above where the centres come from a
            network (:attr:`~bop_cender.net.heatmaps.Heatmaps.centers_from_network`; None: the same as above).
            Ours: 10 and 30 mm. A network's 3D centres are often 5-15 mm off (brackets and shafts, whose
            bounding-box centre is not on the metal; 31 of 69 within 5 mm on a fresh seed-5151 set), where the
            oracle's are within 1-2 mm. Measured on six unseen or test sets with the shipped networks
            (2-core AMD EPYC, 2026-12-06, ``results/accuracy/v15``): DIMO AR_MSSD<5% seed 5151 ``sim`` 0.734 ->
            0.767, ``real`` 0.720 -> 0.736, seed 9002 ``sim`` 0.812 -> 0.806, ``real`` 0.724 -> 0.759; T-LESS AR
            seed 4243 0.456 -> 0.477, seed 6161 0.583 -> 0.584; sigma 10 with the bound 20 gained nothing (5151
            ``sim`` 0.736), the bound 30 with sigma 5 half (0.749). On the oracle the wider search loses (5151
            ``sim`` 0.939 -> 0.926): hence a setting of its own.
        nm_initial_rotation_rad, nm_initial_translation_mm: size of the initial simplex (ours: 0.15 rad, 4 mm).
        nm_xatol: Nelder-Mead ``xatol`` in scaled units (~mm at the part's surface; ours: 0.05).
        nm_fatol: Nelder-Mead ``fatol`` in cost units (pixels; ours: 1e-3).
        nm_maxfev: cost evaluations per Nelder-Mead run (ours: 150; on the test scene 120 and 200 gave the same
            poses to 0.05 mm and 0.1 degree). With the scene polish after the sweeps, oracle AR_MSSD<5% for 300,
            200, 200 with the polish's looser tolerances (``scene_polish_xatol``), and 150: 0.947, 0.949, 0.943,
            0.936 (DIMO seed 9002), 0.958, 0.962, 0.962, 0.976 (seed 4242); AR_MSPD<5px 0.925, 0.925, 0.918,
            0.936 and 0.965, 0.970, 0.970, 0.977: nothing beyond these figures' float-level noise (about 0.01;
            ``results/accuracy/README.md``), for less pose time (``scripts/bench_run.py``).
        candidate_downscale: the random candidates are costed at 1/this resolution (intrinsics scaled,
            distance maps of the max-pooled binary curvature), Nelder-Mead at full resolution; ours: 2
            (4x fewer pixels for the 2,000 candidates; 1 = the paper's single resolution). Render search
            only: the edge search's proxy costs little per pixel and uses the full-resolution maps.
        refiner: ``lockstep`` (the top-k Nelder-Mead runs step together, each step one batched cost call:
            :mod:`bop_cender.pose.simplex`) or ``scipy`` (one ``scipy.optimize.minimize`` per start, the
            paper's). The same algorithm; lockstep is several times faster on the CPU. The edge search
            always steps in lockstep; this chooses for ``search_cost="render"``.
        occlusion: render the objects already placed as occluders of the next ones (the paper's method).
        search_cost: ``edges`` (ours: candidates and most of the refinement on the edge-point proxy, the
            finalists judged and polished on the render cost; see the module docstring) or ``render``
            (the paper's: every evaluation renders).
        edge_segment_mm: edges are cut into segments of at most this length (ours: 3 mm, about 2 pixels
            at DIMO's 320 x 256; see :func:`~bop_cender.pose.edge_model.edge_model`).
        candidate_segments: size of the sparse edge model that ranks the candidates (ours: 600 segments:
            0.2-0.3 ms per candidate in 7 views on one CPU thread, and the 10 best by the render cost
            were all among its 100 best in our measurements).
        rerank: candidates re-ranked by the full edge model before the best ``top_k`` are refined (ours: 100).
        start_separation_rad: the ``top_k`` starts of the edge search are taken best first, each at
            least this far in rotation from the ones before (ours: 0.35 rad, the spacing of 2,000 random
            rotations: without it the starts are often one basin three times); 0: the best ``top_k``. With the
            screen it spreads the screened starts, and again the ``top_k`` that go on (best refined first).
        polish_maxfev: render-cost evaluations of a final polish of the judged best (``edges`` only, from
            a simplex of a quarter of ``nm_initial_*``; ours: 0, none). With one sweep and the paper's
            judge it helped (seed 4242, oracle: AR_MSSD<5% 0.758 with 60, 0.783 with 200). With three sweeps
            judged by the scene it costs accuracy where it is finest and half the pose time: the render
            cost is quantised to the pixel grid, the edge proxy that the search converged on is not
            (bilinear in the distance maps). Measured (``results/accuracy/README.md``), 200 -> 0:
            oracle AR_MSSD<5% 0.835 -> 0.870 (DIMO seed 4242), 0.868 -> 0.843 (seed 9002), T-LESS AR
            0.892 -> 0.891; shipped network 0.397 -> 0.417 (sim, seed 9002), 0.102 -> 0.141 (real), 0.444 -> 0.419 (sim, seed 4242); pose time 0.4-0.5x.
        view_weights: ``center`` (per-view center scores, the paper) or ``uniform``.
        coverage_weight: weight of the coverage term in the two-sided cost that judges the refined poses
            (:mod:`bop_cender.pose.coverage`: the target edges inside a pose's silhouette that it leaves
            unexplained); its total is then also the final cost. 0 (the default): the paper's cost judges.
            1 is the weight that ranked the true pose first most often in the module's diagnosis; as a
            judge alone it changed nothing measurable (see ``passes``), so it is off.
        passes: sweeps over the objects. The first is the paper's sequential placement (each object
            occluded by those placed before it); each further sweep searches every object again, in the
            same order, occluded by all the others as last placed, with its previous pose as one more
            start, and keeps a new pose where ``acceptance`` prefers it; an object that the others hide
            exactly as when it was fitted is skipped (the same search again). Why: an object placed early
            was fitted without the parts lying on it, and a wrong early pose hid the right one of a later
            object. Ours: 3; the paper's is 1. Measured with oracle heatmaps (``results/accuracy/README.md``,
            BOP AR_MSSD<5%, the same 2-core AMD EPYC): with ``acceptance="scene"``, 1 -> 2 passes DIMO-layout
            seed 9002 0.799 -> 0.826, seed 4242 0.791 -> 0.823, T-LESS-layout seed 4243 0.822 -> 0.893 (AR
            0.856 -> 0.891), for 1.2x (DIMO) to 2x (T-LESS) the pose time, and a third pass lost (0.810 on
            seed 9002); with ``acceptance="finalists"``, 2 -> 3 passes 0.841 -> 0.868 (9002), 0.827 -> 0.835
            (4242), 0.893 both (T-LESS), for about 10 % more pose time (a sweep skips the objects whose
            occluders did not change). With ``acceptance="object"`` a second sweep lost on seed 4242 (0.751),
            so that stays an ablation.
        acceptance: what decides whether a further sweep's new pose replaces the old: ``finalists`` (ours,
            the default: every refined finalist of the new search, each start of each candidate id, is
            judged by the scene cost, the symmetric edge distance of all objects rendered together against
            the target, :meth:`~bop_cender.pose.backend.Backend.scene_cost`; the lowest wins if it is below the
            current placement's; with ``polish_maxfev`` > 0 a chosen finalist the search did not polish is
            polished then), ``scene``
            (the same judge for the search's own best only) or ``object`` (the judge's cost of that object
            alone, lower wins). Why the scene: a part moved onto a neighbour's edges costs itself no more,
            but leaves the edges of its true place unexplained and hides the neighbour's; only the scene
            sees that. Why all finalists: where the neighbours are misplaced the object's own cost ranks
            a wrong finalist first, while the scene cost prefers the true pose (DIMO-layout seed 9002,
            scene 000005_00, 9 brackets: each of 5 wrong parts put at its true pose lowers the scene cost,
            though by its own cost its wrong pose wins). Measured with oracle heatmaps
            (``results/accuracy/README.md``), ``scene`` -> ``finalists``: AR_MSSD<5% 0.826 -> 0.841 (seed
            9002), 0.823 -> 0.827 (seed 4242), AR_MSSD 0.875 -> 0.895 and 0.915 -> 0.926, for about 12 %
            more pose time. Only with ``passes`` > 1.
        scene_polish_maxfev: evaluations of the final scene polish of each placed object (ours: 100; see
            :mod:`bop_cender.pose.scene_polish`; 0: none): after the sweeps, each object in order is refined
            by Nelder-Mead (a simplex a quarter of ``nm_initial_*``, within the search's bounds) on the
            scene cost in windows around it, the others fixed, and kept where the full scene cost falls.
            Why: the sweeps choose between poses refined on the edge proxy; where the proxy's minimum and
            the scene's differ by a little (a disc tilted 6 degrees: 5.5 % of its diameter, a miss at the
            strictest threshold), nothing else moves the part to the scene's. Measured with oracle heatmaps
            (``results/accuracy/README.md``), 0 -> 100: AR_MSSD<5% 0.843 -> 0.890 (DIMO seed 9002), 0.870 ->
            0.926 (seed 4242); 200 gave the same as 100 (0.890).
        scene_polish_passes, scene_polish_passes_network: how many times the scene polish goes over the placed
            objects (it stops early where a pass kept no new pose); the second where the centres come from a
            network (None: the first). Ours: 2, and 1 for a network's. Why: stacked parts pull on each other's
            edges, so a part settles only once its neighbour has. Measured (``results/accuracy/README.md``,
            seventeenth session), passes 1 -> 2 -> 3, AR_MSSD<5%: oracle DIMO seed 5151 ``sim`` 0.939 -> 0.977 ->
            0.977 (the pose stage's CPU time 99 -> 139 -> 178 s for the 12 scenes), seed 9002 0.965 at 3 (one pass:
            0.962-0.971); with the shipped network 1 -> 3: 5151 ``sim`` 0.767 -> 0.783 (2: 0.767), ``real`` 0.736 ->
            0.736, 9002 ``sim`` 0.806 -> 0.806, ``real`` 0.759 -> 0.744, T-LESS AR 0.584 -> 0.583 and 0.477 ->
            0.477: no gain for 40-80 % more pose time, so one pass for a network's centres.
        scene_polish_xatol, scene_polish_fatol: the scene polish's Nelder-Mead tolerances (as ``nm_xatol`` and
            ``nm_fatol``; ours: 0.2 and 0.005, looser than the search's 0.05 and 0.001, which the polish never
            reached in its 100 evaluations; with these the 8 parts of the bench's third scene stop after 57-101,
            the scene 22.7 -> 19.1 s under the profiler; the scene cost reached 3.034, against 3.030 with the tight
            tolerances and 300 search evaluations).
        scene_polish_margin_px: the scene polish's window around the projection of an object's bounding
            sphere, in pixels (ours: 12, several times the polish's usual moves).
        center_weight: weight (pixels) of the centre term (ours: 1; 0: the paper's cost alone): every cost
            of the search, the judge of the sweeps and the scene polish adds, per object, how far the
            center heatmap at the projection of the pose's centre falls below its value at the detected 3D
            centre (:func:`center_term`, in [0, 1]). Why: stage 2's centres are more accurate than the
            poses the edges alone give in piles (oracle: 0.3 mm median); without the term parts drifted
            up to the 20 mm translation bound onto a neighbour's edges (DIMO seed 4242, scene 000022_00:
            discs 5-10 mm off their centres). A fixed tighter bound (8 mm) helped the oracle (AR_MSSD<5%
            0.890 -> 0.905, seed 9002) but would hold a network's centres, 10-20 mm off, too tight; the
            heatmap scales the term by how sure the centre is. Measured with the scene polish (oracle):
            0 -> 1 -> 3: 0.890 -> 0.940 -> 0.929 (seed 9002), 0.926 -> 0.967 with 1 (seed 4242). The term is
            part of each object's final cost, so of its BOP score. With ``search_cost="render"`` (the
            paper's search, an ablation) the candidates and their refinement do not see it; the sweeps'
            judge and the scene polish do.
        seed: seed of the candidates (combined with the object's index in the scene).
        screen_starts, screen_maxfev: the edge search's screen (ours: 8 starts, 30 evaluations; 0 starts or at most
            ``top_k``: none, the best ``top_k`` candidates are refined directly): the best ``screen_starts`` diverse
            candidates are refined by a short lockstep Nelder-Mead first, and the ``top_k`` with the lowest refined
            cost, kept ``start_separation_rad`` apart, go on for ``nm_maxfev``. Why: a candidate 10-20 degrees from the
            true pose costs more than the best candidate of a wrong basin, though refined it lands lower (DIMO seed
            9002, scene 000005_00: a fully visible part placed 100 degrees off with the right centre; six starts
            10-20 degrees from its true pose all converge there, at cost 1.82 against the wrong pose's 2.51, but
            none ranked in the top 3). Measured with oracle heatmaps (``results/accuracy/README.md``), screen 0 ->
            8 -> 8 with the continuing starts kept apart (ours) -> 12 (not kept apart): AR_MSSD<5% 0.936 -> 0.949
            -> 0.965 -> 0.965 (DIMO seed 9002), 0.976 -> 0.977 -> 0.969 -> 0.977 (seed 4242); the shipped network
            on seed 9002 ``sim`` 0.627 -> 0.651 -> 0.682; the 8-part bench scene 18.6 -> 17.9 -> 17.4 -> 23.7 s (the
            sets' summed pose time 148 and 281 s with ours, against 164-172 and 287-298 s for the
            unscreened variants measured on the idle machine that day). A screened start may already have moved
            up to the rotation bound, and the continued run is bounded about it again. ``screen_maxfev`` counts
            the initial simplex's 7 evaluations per start, so any screen costs at least those.
        backend: which code computes the renders and costs (:mod:`bop_cender.pose.backend`): ``auto`` (default:
            numba's loops on the CPU, its kernels on CUDA, torch where they cannot run), ``torch`` or ``numba``.
    """

    t_b: float = 0.75
    t_b_network: float | None = None
    n_candidates: int = 2000
    translation_sigma_mm: float = 5.0
    top_k: int = 3
    rotation_bound_rad: float = 0.6
    translation_bound_mm: float = 20.0
    translation_sigma_mm_network: float | None = 10.0
    translation_bound_mm_network: float | None = 30.0
    nm_initial_rotation_rad: float = 0.15
    nm_initial_translation_mm: float = 4.0
    nm_xatol: float = 0.05
    nm_fatol: float = 1e-3
    nm_maxfev: int = 150
    candidate_downscale: int = 2
    refiner: str = "lockstep"
    occlusion: bool = True
    view_weights: str = "center"
    seed: int = 0
    search_cost: str = "edges"
    edge_segment_mm: float = 3.0
    candidate_segments: int = 600
    rerank: int = 100
    start_separation_rad: float = 0.35
    polish_maxfev: int = 0
    coverage_weight: float = 0.0
    passes: int = 3
    acceptance: str = "finalists"
    scene_polish_maxfev: int = 100
    scene_polish_passes: int = 2
    scene_polish_passes_network: int | None = 1
    scene_polish_margin_px: int = 12
    scene_polish_xatol: float = 0.2
    scene_polish_fatol: float = 0.005
    center_weight: float = 1.0
    screen_starts: int = 8
    screen_maxfev: int = 30
    backend: str = "auto"

    def for_network_centers(self) -> PoseConfig:
        """This config with the candidates' spread, the refinement's box and the scene polish's passes of a
        network's centres (``translation_*_network``, ``scene_polish_passes_network`` where set): what stage 3 uses
        when the 3D centres come from a network."""
        sigma, bound = self.translation_sigma_mm_network, self.translation_bound_mm_network
        passes = self.scene_polish_passes_network
        return replace(
            self,
            translation_sigma_mm=self.translation_sigma_mm if sigma is None else sigma,
            translation_bound_mm=self.translation_bound_mm if bound is None else bound,
            scene_polish_passes=self.scene_polish_passes if passes is None else passes,
        )

    def check_refinable(self, field: str) -> None:
        """Refuse more starts to refine than candidates (``top_k`` > ``n_candidates``): the refinement would run fewer
        than asked. Not in :meth:`__post_init__`: ``--set`` applies one setting at a time, and the two may come in
        either order; checked once all are in, by ``run`` (``field``: the option to name).

        Raises:
            ConfigError: naming ``field``.
        """
        if self.top_k > self.n_candidates:
            raise ConfigError(
                f"refines the best {self.top_k} (poses.top_k) of {self.n_candidates} candidates (poses.n_candidates):"
                " give at least as many candidates as starts to refine",
                field=field,
            )

    def __post_init__(self) -> None:
        """Every setting is checked here (named choices, types and ranges), so that a bad ``--set`` is one error
        before any scene runs."""
        for name, allowed in (("search_cost", SEARCH_COSTS), ("refiner", REFINERS), ("view_weights", VIEW_WEIGHTS),
                              ("acceptance", ACCEPTANCES), ("backend", BACKEND_NAMES)):  # fmt: skip
            if getattr(self, name) not in allowed:
                raise ConfigError(
                    f"poses.{name}: expected one of {', '.join(allowed)}, got {getattr(self, name)!r}", field="--set"
                )
        check_settings("poses", self, _POSE_BOUNDS, flags=("occlusion",))


_UNIT_INTERVAL = Bound(0.0, 1.0, high_open=True)
_POSE_BOUNDS = {
    "t_b": _UNIT_INTERVAL,
    "t_b_network": replace(_UNIT_INTERVAL, optional=True),
    "n_candidates": COUNT,
    "translation_sigma_mm": NON_NEGATIVE,
    "top_k": COUNT,
    "rotation_bound_rad": POSITIVE,
    "translation_bound_mm": POSITIVE,
    "translation_sigma_mm_network": replace(NON_NEGATIVE, optional=True),
    "translation_bound_mm_network": replace(POSITIVE, optional=True),
    "nm_initial_rotation_rad": POSITIVE,
    "nm_initial_translation_mm": POSITIVE,
    "nm_xatol": POSITIVE,
    "nm_fatol": POSITIVE,
    "nm_maxfev": COUNT,
    "candidate_downscale": COUNT,
    "seed": Bound(0, integer=True),
    "edge_segment_mm": POSITIVE,
    "candidate_segments": COUNT,
    "rerank": COUNT_OR_ZERO,
    "start_separation_rad": NON_NEGATIVE,
    "polish_maxfev": COUNT_OR_ZERO,
    "coverage_weight": NON_NEGATIVE,
    "passes": COUNT,
    "scene_polish_maxfev": COUNT_OR_ZERO,
    "scene_polish_passes": COUNT,
    "scene_polish_passes_network": replace(COUNT, optional=True),
    "scene_polish_margin_px": COUNT_OR_ZERO,
    "scene_polish_xatol": NON_NEGATIVE,
    "scene_polish_fatol": NON_NEGATIVE,
    "center_weight": NON_NEGATIVE,
    "screen_starts": COUNT_OR_ZERO,
    "screen_maxfev": COUNT_OR_ZERO,
}
"""What each stage-3 setting may be (:func:`~bop_cender.settings_checks.check_settings`)."""


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
            (:meth:`~bop_cender.pose.backend.Backend.candidate_costs` ``workers``: the same bits; worth it with one
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
    f = max(1, int(config.candidate_downscale))
    coarse = fine
    if f > 1 and config.search_cost == "render":  # the edge search costs everything on the fine maps
        pooled = torch.nn.functional.max_pool2d(binary[:, None].float(), f, ceil_mode=True)[:, 0] > 0
        coarse = CostMaps(cameras.downscaled(f), torch.as_tensor(distance_maps(pooled.numpy())).to(device))
    order = sorted(range(len(targets)), key=lambda i: -float(np.sum(targets[i].view_scores)))
    total = len(targets) * config.passes
    edge_threshold = config.t_b * curvature_scale
    backend = backend_named(config.backend)

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
            occ_coarse = _occluder_depth(others, coarse.cameras, meshes, backend)
        rng = np.random.default_rng([config.seed, i] if sweep == 0 else [config.seed, i, sweep])
        return optimise_object(
            targets[i], (coarse, occ_coarse), (fine, occ), meshes, model_centers, config, rng, cost_threads, edges,
            edge_threshold, incumbent=incumbent, finalists=finalists,
        )  # fmt: skip

    placed: list[PlacedObject] = []
    contexts: list[torch.Tensor | None] = []  # the occluder depth each object was last fitted under
    for n, i in enumerate(order):
        occ = _occluder_depth(placed, fine.cameras, meshes, backend) if config.occlusion and placed else None
        placed.append(fit(i, placed, occ, 0, None))
        contexts.append(occ)
        if progress is not None:
            progress(n + 1, total)
    scene_now: float | None = None  # the scene cost of ``placed`` (acceptance scene or finalists), once computed

    # the target of placed[k] is targets[order[k]]
    judge = SceneJudge([targets[i] for i in order], fine, meshes, model_centers, config, edge_threshold)

    for sweep in range(1, config.passes):
        for idx, i in enumerate(order):
            others = placed[:idx] + placed[idx + 1 :]
            occ = _occluder_depth(others, fine.cameras, meshes, backend) if config.occlusion and others else None
            # where nothing hides it differently from when it was fitted, the same search would be repeated
            if _hidden_pixels_differ(placed[idx], contexts[idx], occ, fine.cameras, meshes, backend):
                pool: list[PlacedObject] | None = [] if config.acceptance == "finalists" else None
                moved = fit(i, others, occ, sweep, placed[idx], pool)
                if config.acceptance != "object":
                    if scene_now is None:
                        scene_now = judge.cost(placed)
                    polish = None
                    if config.polish_maxfev > 0:
                        polish = partial(polish_placed, target=targets[i], maps=fine, occluder_depth=occ, meshes=meshes,
                                         model_centers=model_centers, config=config, edge_threshold=edge_threshold)  # fmt: skip
                    moved, scene_now = _choose_by_scene(placed, idx, moved, pool, scene_now, judge.cost, polish)
                placed[idx] = moved
                contexts[idx] = occ  # searched under these occluders, kept or not: a third sweep skips alike
            if progress is not None:
                progress(sweep * len(targets) + idx + 1, total)
    if config.scene_polish_maxfev > 0 and placed:
        for polish_pass in range(config.scene_polish_passes):
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
    polish = replace(
        config,
        nm_initial_rotation_rad=config.nm_initial_rotation_rad / 4,
        nm_initial_translation_mm=config.nm_initial_translation_mm / 4,
        nm_maxfev=config.scene_polish_maxfev,
        nm_xatol=config.scene_polish_xatol,
        nm_fatol=config.scene_polish_fatol,
    )
    if scene_now is None:
        scene_now = judge.cost(placed)
    for idx, obj in enumerate(placed):
        others = placed[:idx] + placed[idx + 1 :]
        window = scene_window(
            meshes(obj.obj_id), obj.T_world_model, [(meshes(o.obj_id), o.T_world_model) for o in others],
            maps.cameras.Ks, maps.cameras.T_cam_world, maps.edges, maps.dist, judge.edge_threshold,
            config.scene_polish_margin_px, judge.backend,
        )  # fmt: skip
        # the occluders only matter for the final cost of a kept pose: rendered then, not for every part
        problem = _refinement(judge.targets[idx], obj.obj_id, maps, None, meshes, judge.model_centers, polish,
                              judge.edge_threshold)  # fmt: skip
        T_new, _, fev = _refine_lockstep(obj.T_world_model[None], problem, partial(_polish_cost, window, problem))
        trial = _with(placed, idx, replace(obj, T_world_model=T_new[0]))
        cost = judge.cost(trial)
        spent = obj.evaluations + fev + 1
        if cost < scene_now:
            if config.occlusion and others:
                problem = replace(problem, occluder_depth=_occluder_depth(others, maps.cameras, meshes, judge.backend))
            final = problem.judge(T_new) + problem.center_term(T_new)
            placed[idx] = PlacedObject(obj.obj_id, T_new[0], float(final[0]), spent + 1)
            scene_now = cost
        else:
            placed[idx] = replace(obj, evaluations=spent)
    return placed


def _choose_by_scene(
    placed: list[PlacedObject],
    idx: int,
    moved: PlacedObject,
    pool: list[PlacedObject] | None,
    scene_now: float,
    scene: Callable[[list[PlacedObject]], float],
    polish: Callable[[PlacedObject], PlacedObject] | None,
) -> tuple[PlacedObject, float]:
    """A further sweep's choice for object ``idx``: of its current pose and the new search's poses (its best
    ``moved``, or with ``acceptance="finalists"`` all its refined finalists ``pool``, the best among them),
    the one whose placement has the lowest scene cost (``scene``); ties keep the current pose. A finalist
    other than the search's best was not polished by the search: it is polished when chosen (``polish``),
    the polished pose kept where the scene does not lose by it.

    Returns the chosen object (its evaluations: all the new search and polish spent) and the scene cost."""
    best, best_cost, spent = placed[idx], scene_now, moved.evaluations
    for option in pool or [moved]:
        cost = scene(_with(placed, idx, option))
        if cost < best_cost:
            best, best_cost = option, cost
    if polish is not None and best is not placed[idx] and not np.array_equal(best.T_world_model, moved.T_world_model):
        polished = polish(best)
        spent += polished.evaluations - best.evaluations
        cost = scene(_with(placed, idx, polished))
        if cost <= best_cost:
            best, best_cost = polished, cost
    return replace(best, evaluations=spent), best_cost


def _with(placed: list[PlacedObject], idx: int, obj: PlacedObject) -> list[PlacedObject]:
    """``placed`` with its ``idx``-th object replaced by ``obj`` (a trial placement)."""
    return placed[:idx] + [obj] + placed[idx + 1 :]


def view_weights(view_scores: np.ndarray, mode: str) -> np.ndarray:
    """``(V,)`` weights summing to 1: the per-view center scores (``center``) or equal (``uniform``)."""
    s = np.clip(np.asarray(view_scores, dtype=np.float64), 0.0, None)
    if mode == "uniform" or s.sum() <= 0:
        return np.full(len(s), 1.0 / len(s))
    if mode != "center":
        raise ValueError(f"unknown view weighting {mode!r}; expected center or uniform")
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
    n = config.n_candidates
    R = Rotation.random(n, random_state=rng).as_matrix()
    centers = target.center[None] + rng.normal(0.0, config.translation_sigma_mm, size=(n, 3))
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
            costs = _cost(
                mesh, T, coarse[0].cameras, coarse[0].dist, problem.weights, coarse[1], problem.backend, cost_threads
            )
            starts = T[np.argsort(costs, kind="stable")[: max(1, config.top_k)]]
            starts = starts if extra is None else np.concatenate([starts, extra])
            refine = _refine_lockstep if config.refiner == "lockstep" else _refine_scipy
            T_ref, c_ref, fev = refine(starts, problem)
            fev += n
            if config.coverage_weight > 0:
                c_ref = problem.judge(T_ref)
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
    config = problem.config
    sparse = model.sparse(config.candidate_segments)
    coarse_costs = problem.search_cost(T, sparse)
    pool = np.argsort(coarse_costs, kind="stable")[: max(1, config.rerank, config.top_k, config.screen_starts)]
    pool = pool[np.argsort(problem.search_cost(T[pool], model), kind="stable")]
    search_cost = partial(problem.search_cost, model=model)
    evaluations = len(T) + len(pool)
    if min(config.screen_starts, len(pool)) > max(1, config.top_k):
        # a short Nelder-Mead from more starts first; the best top_k after it go on (a start 10-20 degrees from
        # the true pose costs more than a wrong basin's best candidate, and only refining shows which is which);
        # those that go on are kept apart in rotation again (screened starts often meet in one basin)
        screened = T[pool[_diverse(T[pool], config.screen_starts, config.start_separation_rad)]]
        short = replace(problem, config=replace(config, nm_maxfev=config.screen_maxfev))
        T_s, f_s, fev = _refine_lockstep(screened, short, search_cost)
        ranked = T_s[np.argsort(f_s, kind="stable")]
        starts = ranked[_diverse(ranked, max(1, config.top_k), config.start_separation_rad)]
        evaluations += fev
    else:
        starts = T[pool[_diverse(T[pool], max(1, config.top_k), config.start_separation_rad)]]
    if extra is not None:
        starts = np.concatenate([starts, extra])
    T_ref, _, fev = _refine_lockstep(starts, problem, search_cost)
    evaluations += fev
    judged = problem.two_sided(T_ref) if config.coverage_weight > 0 else None
    render = problem.cost(T_ref) if judged is None else judged.forward
    final = (render if judged is None else judged.total) + problem.center_term(T_ref)
    evaluations += len(T_ref)
    if config.polish_maxfev > 0:
        k = int(np.argmin(final))
        T_pol, c_pol, fev = _polish_one(T_ref[k], float(render[k]), problem)
        evaluations += fev
        if c_pol is not None:
            T_ref, final = T_ref.copy(), final.copy()
            T_ref[k], final[k] = T_pol, c_pol
    return T_ref, final, evaluations


def _polish(T: np.ndarray, problem: Refinement) -> tuple[np.ndarray, np.ndarray, int]:
    """The final polish of poses ``T (m, 4, 4)``: Nelder-Mead on the render cost from a simplex a quarter of
    ``nm_initial_*``, ``polish_maxfev`` evaluations. Returns poses, render costs ``(m,)`` and evaluations."""
    config = problem.config
    polish = replace(
        config,
        nm_initial_rotation_rad=config.nm_initial_rotation_rad / 4,
        nm_initial_translation_mm=config.nm_initial_translation_mm / 4,
        nm_maxfev=config.polish_maxfev,
    )
    return _refine_lockstep(T, replace(problem, config=polish))


def _polish_one(T: np.ndarray, render_cost: float, problem: Refinement) -> tuple[np.ndarray, float | None, int]:
    """Pose ``T (4, 4)`` of render cost ``render_cost`` polished (:func:`_polish`): the polished pose and its final
    cost (the render cost, or judged again with ``coverage_weight`` > 0, plus the centre term) where the
    polish lowered the render cost plus the centre term, else ``T`` and None; and the evaluations spent."""
    T_pol, c_pol, fev = _polish(T[None], problem)
    center_pol = float(problem.center_term(T_pol)[0])
    if not c_pol[0] + center_pol < render_cost + float(problem.center_term(T[None])[0]):
        return T, None, fev
    final = float(c_pol[0]) if problem.config.coverage_weight <= 0 else float(problem.judge(T_pol)[0])
    return T_pol[0], final + center_pol, fev


def polish_placed(
    obj: PlacedObject,
    target: PoseTarget,
    maps: CostMaps,
    occluder_depth: torch.Tensor | None,
    meshes: Callable[[int], RenderMesh],
    model_centers: Callable[[int], np.ndarray],
    config: PoseConfig,
    edge_threshold: float | None = None,
) -> PlacedObject:
    """``obj`` polished (:func:`_polish_one`) against the full-resolution ``maps`` under ``occluder_depth``
    where that lowers its render cost, else ``obj`` (its evaluations counted either way). For a finalist
    that was not its search's best, so not polished there (``acceptance="finalists"``)."""
    problem = _refinement(target, obj.obj_id, maps, occluder_depth, meshes, model_centers, config, edge_threshold)
    T, cost, fev = _polish_one(obj.T_world_model, float(problem.cost(obj.T_world_model[None])[0]), problem)
    evaluations = obj.evaluations + fev + 1
    if cost is None:
        return replace(obj, evaluations=evaluations)
    return PlacedObject(obj.obj_id, T, cost, evaluations)


def _polish_cost(window: SceneWindow, problem: Refinement, T_world_model: np.ndarray) -> np.ndarray:
    """``(n,)`` what the scene polish minimises for poses ``(n, 4, 4)``: the windowed scene cost plus the centre term."""
    return problem.backend.window_costs(window, T_world_model) + problem.center_term(T_world_model)


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
    weights = torch.as_tensor(
        view_weights(target.view_scores, config.view_weights), dtype=torch.float32, device=maps.dist.device
    )
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
    backend: Backend,
    threads: int = 1,
) -> np.ndarray:
    """``(n,)`` float64 costs of ``T_world_model (n, 4, 4)`` in all views (``threads``: chunk threads)."""
    T_cm = np.einsum("vij,njk->nvik", cameras.T_cam_world, T_world_model)
    out = backend.candidate_costs(
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

    @property
    def backend(self) -> Backend:
        """The backend of ``config.backend`` (:func:`~bop_cender.pose.backend.backend_named`: one per run)."""
        return backend_named(self.config.backend)

    @cached_property
    def edge_occluder(self) -> torch.Tensor | None:
        """The occluder depth widened for the edge cost (:func:`~bop_cender.pose.edge_cost.edge_occluder`)."""
        return None if self.occluder_depth is None else edge_occluder(self.occluder_depth)

    def cost(self, T_world_model: np.ndarray) -> np.ndarray:
        """``(n,)`` render costs of poses ``(n, 4, 4)``."""
        return _cost(self.mesh, T_world_model, self.cameras, self.dist, self.weights, self.occluder_depth, self.backend)

    def two_sided(self, T_world_model: np.ndarray) -> TwoSidedCost:
        """The two-sided costs (:func:`~bop_cender.pose.coverage.two_sided_costs`) of poses ``(n, 4, 4)``."""
        if self.target_edges is None or self.edge_threshold is None:
            raise ValueError("the two-sided cost needs the target's binarised curvature and the edge threshold")
        T_cm = np.einsum("vij,njk->nvik", self.cameras.T_cam_world, T_world_model)
        return two_sided_costs(
            self.mesh,
            torch.as_tensor(T_cm, dtype=torch.float32, device=self.dist.device),
            torch.as_tensor(self.cameras.Ks, dtype=torch.float32, device=self.dist.device),
            self.target_edges,
            self.dist,
            self.weights,
            self.edge_threshold,
            self.config.coverage_weight,
            self.occluder_depth,
            self.backend,
        )

    def judge(self, T_world_model: np.ndarray) -> np.ndarray:
        """``(n,)`` final costs of poses ``(n, 4, 4)``: two-sided where ``coverage_weight > 0``, else the render cost."""
        return self.two_sided(T_world_model).total if self.config.coverage_weight > 0 else self.cost(T_world_model)

    def search_cost(self, T_world_model: np.ndarray, model: EdgeModel) -> np.ndarray:
        """``(n,)`` what the edge search ranks and refines poses ``(n, 4, 4)`` by: the edge cost plus the centre term."""
        return self.edge_cost(T_world_model, model) + self.center_term(T_world_model)

    def edge_cost(self, T_world_model: np.ndarray, model: EdgeModel) -> np.ndarray:
        """``(n,)`` edge-point costs (:meth:`~bop_cender.pose.backend.Backend.edge_costs`) of poses ``(n, 4, 4)``."""
        T_cm = np.einsum("vij,njk->nvik", self.cameras.T_cam_world, T_world_model)
        out = self.backend.edge_costs(
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


def _bounds_and_starts(starts: np.ndarray, center3d: np.ndarray, center_model: np.ndarray, config: PoseConfig):
    rb = config.rotation_bound_rad * ROTATION_SCALE_MM
    tb = config.translation_bound_mm
    lo = np.concatenate([np.full(3, -rb), np.full(3, -tb)])
    c0 = np.einsum("kij,j->ki", starts[:, :3, :3], center_model) + starts[:, :3, 3]
    x0 = np.concatenate([np.zeros((len(starts), 3)), np.clip(c0 - center3d, -tb, tb)], axis=1)
    step = np.concatenate(
        [np.full(3, config.nm_initial_rotation_rad * ROTATION_SCALE_MM), np.full(3, config.nm_initial_translation_mm)]
    )
    return x0, step, lo, -lo


def _refine_lockstep(
    starts: np.ndarray, problem: Refinement, cost: Callable[[np.ndarray], np.ndarray] | None = None
) -> tuple[np.ndarray, np.ndarray, int]:
    """All starts ``(k, 4, 4)`` refined together (:func:`bop_cender.pose.simplex.batched_nelder_mead`) on
    ``cost`` (poses ``(m, 4, 4)`` -> ``(m,)``; default the render cost, ``problem.cost``).

    Returns the refined poses ``(k, 4, 4)``, their costs ``(k,)`` and the evaluations spent."""
    cost = problem.cost if cost is None else cost
    from bop_cender.pose.simplex import batched_nelder_mead

    config = problem.config
    x0, step, lo, hi = _bounds_and_starts(starts, problem.center3d, problem.center_model, config)
    param = _Perturbation(starts[:, :3, :3], problem.center3d, problem.center_model)
    k = len(starts)
    # Each point carries the index of its start as a 7th coordinate that never moves (step 0, bounds
    # [0, k - 1]; every simplex vertex and reflection of start i keeps the value i).
    x0 = np.concatenate([x0, np.arange(k, dtype=np.float64)[:, None]], axis=1)
    step, lo, hi = np.append(step, 0.0), np.append(lo, 0.0), np.append(hi, float(k - 1))

    def f(x: np.ndarray) -> np.ndarray:
        owner = np.rint(x[:, -1]).astype(np.int64)
        return cost(param.poses(x[:, :-1], owner))

    x_best, f_best, nfev = batched_nelder_mead(f, x0, step, lo, hi, config.nm_xatol, config.nm_fatol, config.nm_maxfev)
    return param.poses(x_best[:, :-1], np.arange(k)), f_best, int(nfev.sum())


def _refine_scipy(starts: np.ndarray, problem: Refinement) -> tuple[np.ndarray, np.ndarray, int]:
    """Each start refined by its own ``scipy.optimize.minimize(method="Nelder-Mead", bounds=...)`` (the paper's)."""
    config = problem.config
    x0, step, lo, hi = _bounds_and_starts(starts, problem.center3d, problem.center_model, config)
    param = _Perturbation(starts[:, :3, :3], problem.center3d, problem.center_model)
    poses, costs, total = [], [], 0
    for i in range(len(starts)):
        which = np.array([i])

        def f(x: np.ndarray, which=which) -> float:
            return float(problem.cost(param.poses(x[None], which))[0])

        simplex = np.clip(np.vstack([x0[i], x0[i] + np.diag(step)]), lo, hi)
        res = minimize(
            f,
            x0[i],
            method="Nelder-Mead",
            bounds=list(zip(lo, hi, strict=True)),
            options={"initial_simplex": simplex, "xatol": config.nm_xatol, "fatol": config.nm_fatol,
                     "maxfev": config.nm_maxfev},
        )  # fmt: skip
        poses.append(param.poses(res.x[None], which)[0])
        costs.append(float(res.fun))
        total += int(res.nfev)
    return np.stack(poses), np.array(costs), total


def _hidden_pixels_differ(
    obj: PlacedObject,
    before: torch.Tensor | None,
    after: torch.Tensor | None,
    cameras: SceneCameras,
    meshes: Callable[[int], RenderMesh],
    backend: Backend,
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
        backend=backend,
    ).depth

    def hidden(occ: torch.Tensor | None) -> torch.Tensor:
        return torch.zeros_like(depth, dtype=torch.bool) if occ is None else occluded(depth, occ)

    return not torch.equal(hidden(before), hidden(after))


def _scene_cost(
    placed: Sequence[PlacedObject],
    maps: CostMaps,
    meshes: Callable[[int], RenderMesh],
    edge_threshold: float,
    backend: Backend,
) -> float:
    """The scene cost (:meth:`~bop_cender.pose.backend.Backend.scene_cost`) of ``placed`` against the full-resolution ``maps``."""
    T_wm = np.stack([p.T_world_model for p in placed])
    T_cm = np.einsum("vij,mjk->vmik", maps.cameras.T_cam_world, T_wm)
    return backend.scene_cost(
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

    @property
    def backend(self) -> Backend:
        """The backend of ``config.backend`` (:func:`~bop_cender.pose.backend.backend_named`: one per run)."""
        return backend_named(self.config.backend)

    def cost(self, placed: Sequence[PlacedObject]) -> float:
        """What the sweeps and the scene polish judge ``placed`` by: its scene cost (:func:`_scene_cost`) plus,
        with ``center_weight`` > 0, each object's :func:`center_term`."""
        cost = _scene_cost(placed, self.maps, self.meshes, self.edge_threshold, self.backend)
        if self.config.center_weight > 0:
            for obj, target in zip(placed, self.targets, strict=True):
                w = view_weights(target.view_scores, self.config.view_weights)
                cost += float(center_term(obj.T_world_model[None], self.model_centers(obj.obj_id), target.view_scores,
                                          target.center_map, w, self.maps.cameras, self.config.center_weight)[0])  # fmt: skip
        return cost


def _occluder_depth(
    placed: Sequence[PlacedObject], cameras: SceneCameras, meshes: Callable[[int], RenderMesh], backend: Backend
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
        backend=backend,
    )
    return render.depth
