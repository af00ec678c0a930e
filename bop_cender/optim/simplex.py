"""Nelder-Mead on several starts at once: the k simplices step in lockstep and every step costs their
new points in one batched call.

Why not ``scipy.optimize.minimize(method="Nelder-Mead")`` for each start: on the CPU a cost call for one
pose spends most of its time in per-call overhead (hundreds of small torch operations; 5-25 ms against
2-5 ms per pose in a batch of hundreds), so k sequential runs cost k times one run while k simplices
in lockstep cost barely more than one. The algorithm is the textbook one as scipy implements it
(reflection 1, expansion 2, contraction 0.5, shrink 0.5; inside and outside contraction; the same
stopping rule: every vertex within ``xatol`` of the best in every coordinate and every value within
``fatol`` of the best, or the evaluation budget spent) and, as scipy's bounded variant does, points are
clipped into the box before they are costed. A simplex that has converged stops being costed while
the others go on.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

ALPHA, GAMMA, RHO, SIGMA = 1.0, 2.0, 0.5, 0.5


def batched_nelder_mead(
    f: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    step: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    xatol: float = 1e-4,
    fatol: float = 1e-4,
    maxfev: int = 400,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimise ``f`` from ``k`` starts at once.

    Args:
        f: costs ``(m,)`` of points ``(m, n)`` (any m; called with the points of all active simplices).
        x0: ``(k, n)`` starts.
        step: ``(n,)`` initial simplex: vertex i is ``x0 + step_i e_i``.
        lo, hi: ``(n,)`` bounds; every point is clipped into them.
        xatol, fatol: convergence tolerances (as scipy's).
        maxfev: evaluations per start.

    Returns:
        ``x (k, n)`` the best vertex of each simplex, ``fx (k,)`` its cost, ``nfev (k,)`` evaluations spent.
    """
    x0 = np.clip(np.asarray(x0, dtype=np.float64), lo, hi)
    k, n = x0.shape
    sim = np.repeat(x0[:, None], n + 1, axis=1)  # (k, n+1, n)
    sim[:, 1:] += np.diag(np.asarray(step, dtype=np.float64))[None]
    sim = np.clip(sim, lo, hi)
    fsim = f(sim.reshape(-1, n)).reshape(k, n + 1)
    nfev = np.full(k, n + 1)
    active = np.ones(k, dtype=bool)
    while True:
        order = np.argsort(fsim, axis=1, kind="stable")
        sim = np.take_along_axis(sim, order[..., None], 1)
        fsim = np.take_along_axis(fsim, order, 1)
        converged = (np.abs(sim[:, 1:] - sim[:, :1]).max(axis=(1, 2)) <= xatol) & (
            np.abs(fsim[:, 1:] - fsim[:, :1]).max(axis=1) <= fatol
        )
        active &= ~converged & (nfev < maxfev)
        idx = np.flatnonzero(active)
        if len(idx) == 0:
            break
        s, fs = sim[idx], fsim[idx]
        centroid = s[:, :-1].mean(axis=1)
        worst = s[:, -1]
        xr = np.clip(centroid + ALPHA * (centroid - worst), lo, hi)
        fr = f(xr)
        nfev[idx] += 1
        expand = fr < fs[:, 0]
        accept = (fr >= fs[:, 0]) & (fr < fs[:, -2])
        outside = (fr >= fs[:, -2]) & (fr < fs[:, -1])
        inside = fr >= fs[:, -1]
        # second points: expansion, outside or inside contraction, one batched call
        second = np.where(
            expand[:, None],
            centroid + GAMMA * (xr - centroid),
            np.where(outside[:, None], centroid + RHO * (xr - centroid), centroid + RHO * (worst - centroid)),
        )
        second = np.clip(second, lo, hi)
        need = expand | outside | inside
        f2 = np.full(len(idx), np.inf)
        if need.any():
            f2[need] = f(second[need])
            nfev[idx[need]] += 1
        new_x, new_f = worst.copy(), fs[:, -1].copy()
        take_e = expand & (f2 < fr)
        take_r = (expand & ~take_e) | accept
        take_oc = outside & (f2 <= fr)
        take_ic = inside & (f2 < fs[:, -1])
        for mask, xs, fv in ((take_e, second, f2), (take_r, xr, fr), (take_oc, second, f2), (take_ic, second, f2)):
            new_x[mask], new_f[mask] = xs[mask], fv[mask]
        shrink = (outside & ~take_oc) | (inside & ~take_ic)
        s[:, -1], fs[:, -1] = new_x, new_f
        if shrink.any():
            shr = s[shrink]
            shr[:, 1:] = np.clip(shr[:, :1] + SIGMA * (shr[:, 1:] - shr[:, :1]), lo, hi)
            fs_shr = fs[shrink]
            fs_shr[:, 1:] = f(shr[:, 1:].reshape(-1, n)).reshape(-1, n)
            s[shrink], fs[shrink] = shr, fs_shr
            nfev[idx[shrink]] += n
        sim[idx], fsim[idx] = s, fs
    best = np.argmin(fsim, axis=1)
    return sim[np.arange(k), best], fsim[np.arange(k), best], nfev
