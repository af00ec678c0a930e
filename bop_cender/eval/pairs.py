"""The (estimate, GT) pairs the scorer computes errors for, as arrays: what :mod:`bop_cender.eval.pair_errors` and
:mod:`bop_cender.eval.pair_vsd` both take (a module of its own, below both)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bop_cender.eval.ground_truth import ImageGt


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
