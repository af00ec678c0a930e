"""Stage-3 setting names of before the config's sections (issue 41), for errors that give the new name.

``--set poses.nm_maxfev=200`` from an older command line or notebook is refused with one message naming the new
place of the setting (:data:`RENAMED`), or saying that the option was removed and where its figures are
(:data:`REMOVED`): never a silent no-op and never a bare "unknown setting". Names are relative to ``poses``.
"""

from __future__ import annotations

#: Where each measured figure of a removed option is kept.
FIGURES = 'results/accuracy/README.md, section "Stage-3 settings: how each default was measured"'

#: Old flat name -> its path in :class:`~bop_cender.pose.config.PoseConfig`'s sections.
RENAMED: dict[str, str] = {
    "t_b_network": "network.t_b",
    "n_candidates": "candidates.n",
    "translation_sigma_mm": "candidates.translation_sigma_mm",
    "top_k": "candidates.top_k",
    "candidate_downscale": "candidates.downscale",
    "candidate_segments": "candidates.segments",
    "rerank": "candidates.rerank",
    "start_separation_rad": "candidates.start_separation_rad",
    "rotation_bound_rad": "refine.rotation_bound_rad",
    "translation_bound_mm": "refine.translation_bound_mm",
    "translation_sigma_mm_network": "network.translation_sigma_mm",
    "translation_bound_mm_network": "network.translation_bound_mm",
    "nm_initial_rotation_rad": "refine.nelder_mead.initial_rotation_rad",
    "nm_initial_translation_mm": "refine.nelder_mead.initial_translation_mm",
    "nm_xatol": "refine.nelder_mead.xatol",
    "nm_fatol": "refine.nelder_mead.fatol",
    "nm_maxfev": "refine.nelder_mead.maxfev",
    "passes": "sweeps.passes",
    "scene_polish_maxfev": "scene_polish.nelder_mead.maxfev",
    "scene_polish_passes": "scene_polish.passes",
    "scene_polish_passes_network": "network.scene_polish_passes",
    "scene_polish_margin_px": "scene_polish.margin_px",
    "scene_polish_xatol": "scene_polish.nelder_mead.xatol",
    "scene_polish_fatol": "scene_polish.nelder_mead.fatol",
    "screen_starts": "screen.starts",
    "screen_maxfev": "screen.nelder_mead.maxfev",
}

#: Old name -> what else it set before the sections, where one old setting drove several Nelder-Mead runs: following
#: :data:`RENAMED` alone would change the refinement's run only (default runs are unaffected).
ALSO: dict[str, str] = {
    "nm_initial_rotation_rad": "it also set poses.screen.nelder_mead.initial_rotation_rad, and a quarter of it"
    " poses.scene_polish.nelder_mead.initial_rotation_rad: set those too for the old behaviour",
    "nm_initial_translation_mm": "it also set poses.screen.nelder_mead.initial_translation_mm, and a quarter of it"
    " poses.scene_polish.nelder_mead.initial_translation_mm: set those too for the old behaviour",
    "nm_xatol": "it also set poses.screen.nelder_mead.xatol: set that too for the old behaviour",
    "nm_fatol": "it also set poses.screen.nelder_mead.fatol: set that too for the old behaviour",
}

#: Removed option -> why (each was off by default; its figures, where it had any, are in :data:`FIGURES`).
REMOVED: dict[str, str] = {
    "coverage_weight": "the two-sided judge measured no gain alone (2026-12-02, second session)",
    "polish_maxfev": "the render-cost polish lost with three sweeps judged by the scene (2026-12-03)",
    "acceptance": "a further sweep always judges every refined finalist by the scene cost; 'scene' and 'object'"
    " measured lower (2026-12-02 and 2026-12-03)",
    "refiner": "the lockstep Nelder-Mead is scipy's algorithm (tests/optim/test_simplex.py); no figure asked for"
    " scipy's driver",
    "view_weights": "the views are weighted by their center scores, the paper's; no figure asked for 'uniform'",
}
