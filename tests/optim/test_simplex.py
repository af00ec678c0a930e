"""The lockstep Nelder-Mead: the same minima as scipy's, several starts at once, bounds respected."""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize, rosen

from bop_cender.optim.simplex import batched_nelder_mead


def test_quadratic_from_several_starts():
    target = np.array([1.0, -2.0, 0.5])
    calls = []

    def f(x):
        calls.append(len(x))
        return ((x - target) ** 2 * [1, 4, 9]).sum(1)

    x0 = np.array([[0.0, 0, 0], [3.0, 3, 3], [-2.0, 1, 0]])
    x, fx, nfev = batched_nelder_mead(f, x0, np.full(3, 0.5), np.full(3, -10), np.full(3, 10), 1e-6, 1e-10, 2000)
    np.testing.assert_allclose(x, np.repeat(target[None], 3, 0), atol=1e-4)
    assert fx.max() < 1e-8 and (nfev < 2000).all()
    assert max(calls) > 1  # the starts were costed together


def test_rosenbrock_matches_scipy():
    x0 = np.array([[-1.2, 1.0]])
    x, fx, _ = batched_nelder_mead(lambda p: np.array([rosen(q) for q in p]), x0, np.array([0.05 * 1.2, 0.05]),
                                   np.full(2, -5.0), np.full(2, 5.0), 1e-8, 1e-8, 5000)  # fmt: skip
    ref = minimize(rosen, x0[0], method="Nelder-Mead", options={"xatol": 1e-8, "fatol": 1e-8, "maxfev": 5000})
    np.testing.assert_allclose(x[0], ref.x, atol=1e-5)
    np.testing.assert_allclose(x[0], [1.0, 1.0], atol=1e-5)


def test_bounds_clip_the_minimum():
    x, fx, _ = batched_nelder_mead(lambda p: ((p - 5.0) ** 2).sum(1), np.zeros((2, 2)), np.full(2, 0.3),
                                   np.full(2, -1.0), np.full(2, 1.0), 1e-7, 1e-9, 1000)  # fmt: skip
    np.testing.assert_allclose(x, 1.0, atol=1e-5)


def test_budget_is_respected():
    x, fx, nfev = batched_nelder_mead(lambda p: np.array([rosen(q) for q in p]), np.array([[-1.2, 1.0]]),
                                      np.full(2, 0.1), np.full(2, -5.0), np.full(2, 5.0), 0, 0, 50)  # fmt: skip
    assert nfev[0] <= 50 + 2
