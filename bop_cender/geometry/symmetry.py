"""BOP symmetry transformations of an object model, exactly as the official toolkit builds them.

Reimplemented from the toolkit's definition (``misc.get_symmetry_transformations``; docs/evaluation.md): the
discrete set is the identity followed by every entry of ``symmetries_discrete`` (flattened row-major 4x4, mm).
Each continuous symmetry ``{axis, offset}`` becomes ``n = ceil(pi / max_sym_disc_step)`` rotations by
``k * 2 pi / n`` (k = 0..n-1, so the identity is included) about ``axis`` through ``offset``, with
``t_k = -R_k offset + offset``. If any continuous symmetry exists the result is every pair (discrete outer,
continuous inner) composed as ``R = R_c R_d``, ``t = R_c t_d + t_c``; otherwise the discrete set. A symmetry
``(R_s, t_s)`` acts on the GT pose: ``R_g' = R_g R_s``, ``t_g' = R_g t_s + t_g``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from bop_cender.geometry.rotations import orthonormality_error

#: BOP'19 evaluation's discretisation step (fraction of the diameter), eval_bop19_pose.py.
BOP19_MAX_SYM_DISC_STEP = 0.01
#: A discrete symmetry whose rotation part is farther than this from orthonormal (max |R R^T - I|) is refused:
#: the files round them to ~6 digits, and a scaling or a zero matrix would make every MSSD / MSPD meaningless.
SYMMETRY_TOLERANCE = 1e-2


@dataclass(frozen=True)
class ContinuousSymmetry:
    """Rotational symmetry about ``axis (3,)`` through the point ``offset (3,)`` (mm, model frame)."""

    axis: tuple[float, float, float]
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)


def continuous_step_count(max_sym_disc_step: float = BOP19_MAX_SYM_DISC_STEP) -> int:
    """Number of rotations a continuous symmetry is sampled at: ``ceil(pi / step)`` (315 for 0.01)."""
    return int(math.ceil(math.pi / max_sym_disc_step))


def _rotation_about_axis(angle: float, axis: np.ndarray) -> np.ndarray:
    """Rodrigues rotation ``(3, 3)`` about a (normalised) axis; the toolkit's rotation_matrix."""
    a = axis / np.linalg.norm(axis)
    s, c = math.sin(angle), math.cos(angle)
    cross = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return c * np.eye(3) + s * cross + (1.0 - c) * np.outer(a, a)


def symmetry_transforms(
    discrete: Sequence[Sequence[float]] | np.ndarray = (),
    continuous: Sequence[ContinuousSymmetry] = (),
    max_sym_disc_step: float = BOP19_MAX_SYM_DISC_STEP,
) -> tuple[np.ndarray, np.ndarray]:
    """All symmetry transformations, identity first.

    Args:
        discrete: flattened row-major 4x4 matrices (16 floats each), as in ``models_info.json``.
        continuous: continuous rotational symmetries.
        max_sym_disc_step: BOP's discretisation step (0.01 in BOP'19 evaluation).

    Returns:
        ``R (S, 3, 3)`` and ``t (S, 3)`` float64, in the toolkit's order.
    """
    R_disc = [np.eye(3)]
    t_disc = [np.zeros(3)]
    for flat in discrete:
        m = np.asarray(flat, dtype=np.float64).reshape(4, 4)
        R_disc.append(m[:3, :3])
        t_disc.append(m[:3, 3])
    R_cont: list[np.ndarray] = []
    t_cont: list[np.ndarray] = []
    n = continuous_step_count(max_sym_disc_step)
    step = 2.0 * math.pi / n
    for sym in continuous:
        axis = np.asarray(sym.axis, dtype=np.float64)
        offset = np.asarray(sym.offset, dtype=np.float64)
        for k in range(n):
            Rk = _rotation_about_axis(k * step, axis)
            R_cont.append(Rk)
            t_cont.append(-Rk @ offset + offset)
    if not R_cont:
        return np.stack(R_disc), np.stack(t_disc)
    Rc = np.stack(R_cont)  # (C, 3, 3)
    tc = np.stack(t_cont)  # (C, 3)
    Rd = np.stack(R_disc)  # (D, 3, 3)
    td = np.stack(t_disc)  # (D, 3)
    R = np.einsum("cij,djk->dcik", Rc, Rd).reshape(-1, 3, 3)
    t = (np.einsum("cij,dj->dci", Rc, td) + tc[None]).reshape(-1, 3)
    return R, t


def symmetries_from_model_info(info: Mapping) -> tuple[list[list[float]], list[ContinuousSymmetry]]:
    """Read ``symmetries_discrete`` and ``symmetries_continuous`` from one models_info entry.

    Raises ValueError (with the key) on malformed entries; loaders turn it into a DatasetError.
    """
    discrete: list[list[float]] = []
    for i, flat in enumerate(_symmetry_list(info, "symmetries_discrete")):
        arr = _floats(flat)
        if arr is None or arr.shape != (16,) or not np.all(np.isfinite(arr)):
            raise ValueError(f"symmetries_discrete[{i}]: expected 16 finite numbers (row-major 4x4)")
        m = arr.reshape(4, 4)
        err, det = float(orthonormality_error(m[:3, :3])), float(np.linalg.det(m[:3, :3]))
        if err > SYMMETRY_TOLERANCE or det < 0 or not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
            raise ValueError(
                f"symmetries_discrete[{i}]: expected a rigid transform (max |R R^T - I| = {err:.3g}, det = {det:.4f};"
                f" expected <= {SYMMETRY_TOLERANCE:g}, det +1 and last row 0 0 0 1)"
            )
        discrete.append(arr.tolist())
    continuous: list[ContinuousSymmetry] = []
    for i, sym in enumerate(_symmetry_list(info, "symmetries_continuous")):
        if not isinstance(sym, Mapping) or "axis" not in sym:
            raise ValueError(f"symmetries_continuous[{i}]: expected an object with 'axis' and 'offset'")
        axis, offset = _floats(sym["axis"]), _floats(sym.get("offset", [0, 0, 0]))
        if (
            axis is None
            or offset is None
            or axis.shape != (3,)
            or offset.shape != (3,)
            or not np.all(np.isfinite(np.r_[axis, offset]))
        ):
            raise ValueError(f"symmetries_continuous[{i}]: axis and offset must be 3 finite numbers")
        if np.linalg.norm(axis) == 0:
            raise ValueError(f"symmetries_continuous[{i}].axis: must not be the zero vector")
        continuous.append(ContinuousSymmetry(tuple(axis.tolist()), tuple(offset.tolist())))
    return discrete, continuous


def _symmetry_list(info: Mapping, key: str) -> list:
    """``info[key]``: a list; absent or null is no symmetry (anything else, a number or a string, is refused)."""
    value = info.get(key)
    if value is None:
        return []
    if not isinstance(value, list):
        raise ValueError(f"{key}: expected a list, got {type(value).__name__}")
    return value


def _floats(value: object) -> np.ndarray | None:
    """``value`` as a float64 array, None where it is not numbers (an object, a string, a bool)."""
    if isinstance(value, bool) or (isinstance(value, list) and any(isinstance(v, bool) for v in value)):
        return None
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        return None


def apply_symmetries_to_pose(
    R_gt: np.ndarray, t_gt: np.ndarray, sym_R: np.ndarray, sym_t: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric variants of a GT pose: ``R (S, 3, 3) = R_g R_s``, ``t (S, 3) = R_g t_s + t_g``."""
    return np.einsum("ij,sjk->sik", R_gt, sym_R), sym_t @ np.asarray(R_gt).T + np.asarray(t_gt).reshape(1, 3)
