"""Stage 3's bounded Nelder-Mead: starts refined in lockstep over a rotation-vector perturbation and the centre.

A pose is refined as ``x = (rotvec * ROTATION_SCALE_MM, centre - center3d)`` about its start rotation
(:class:`Perturbation`): six parameters of about a millimetre at the part's surface each, the rotation within
``poses.refine.rotation_bound_rad`` and the centre within a box of ``poses.refine.translation_bound_mm`` about the
detected 3D centre. All starts step together (:func:`bop_cender.optim.simplex.batched_nelder_mead`), each step one
batched cost call; the settings of each run (the refinement's, the screen's, the scene polish's) are a
:class:`~bop_cender.pose.config.NelderMead`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from bop_cender.optim.simplex import batched_nelder_mead
from bop_cender.pose.config import NelderMead, PoseConfig
from bop_cender.pose.problem import Refinement, pose_matrices

#: Nelder-Mead works on rotation-vector perturbations scaled by this (mm per radian, about a part's
#: radius), so that one unit of either parameter moves a surface point by about a millimetre.
ROTATION_SCALE_MM = 50.0


def refine(
    starts: np.ndarray,
    problem: Refinement,
    cost: Callable[[np.ndarray], np.ndarray] | None = None,
    nelder_mead: NelderMead | None = None,
) -> tuple[np.ndarray, np.ndarray, int]:
    """All starts ``(k, 4, 4)`` refined together on ``cost`` (poses ``(m, 4, 4)`` -> ``(m,)``; default the render
    cost, ``problem.cost``) with ``nelder_mead`` (default ``poses.refine.nelder_mead``), within the refinement's
    bounds about ``problem``'s 3D centre.

    Returns the refined poses ``(k, 4, 4)``, their costs ``(k,)`` and the evaluations spent."""
    cost = problem.cost if cost is None else cost
    config = problem.config
    nm = config.refine.nelder_mead if nelder_mead is None else nelder_mead
    x0, step, lo, hi = bounds_and_starts(starts, problem.center3d, problem.center_model, config, nm)
    param = Perturbation(starts[:, :3, :3], problem.center3d, problem.center_model)
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


@dataclass(frozen=True)
class Perturbation:
    """Nelder-Mead's parameters ``x = (rotvec * ROTATION_SCALE_MM, centre - center3d)`` around start rotations."""

    R0: np.ndarray  # (k, 3, 3)
    center3d: np.ndarray  # (3,)
    center_model: np.ndarray  # (3,)

    def poses(self, x: np.ndarray, start: np.ndarray) -> np.ndarray:
        """``T_world_model (m, 4, 4)`` of parameters ``x (m, 6)`` applied to starts ``start (m,)``."""
        R = Rotation.from_rotvec(x[:, :3] / ROTATION_SCALE_MM).as_matrix() @ self.R0[start]
        return pose_matrices(R, self.center3d[None] + x[:, 3:], self.center_model)


def bounds_and_starts(
    starts: np.ndarray, center3d: np.ndarray, center_model: np.ndarray, config: PoseConfig, nelder_mead: NelderMead
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The parameters of poses ``starts (k, 4, 4)`` (``x0 (k, 6)``: no rotation, the centre's offset clipped into the
    box), the initial simplex's ``step (6,)`` and the bounds ``lo, hi (6,)``."""
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
