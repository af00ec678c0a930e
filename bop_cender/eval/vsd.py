"""Visible Surface Discrepancy (VSD) on already-rendered depth images, as BOP'19 computes it.

Follows the toolkit (docs/evaluation.md; ``pose_error.vsd`` with
``visibility.estimate_visib_mask_gt/est`` in ``"bop19"`` mode and cost ``"step"``), to the bit:

1. depth -> distance images with :func:`depth_to_distance` (float64, integer pixel indices);
2. visibility, with the differences taken in float32 as the toolkit does::

       visib_gt  = (d_gt  - d_test <= delta  OR  d_test == 0) AND d_gt  > 0
       visib_est = [(d_est - d_test <= delta OR d_test == 0) AND d_est > 0] OR [visib_gt AND d_est > 0]

   (a pixel with missing test depth counts as visible);
3. ``dists = |d_gt - d_est|`` on ``visib_gt & visib_est`` (/ diameter if normalised);
4. per tau: ``e = (#(dists >= tau) + |union| - |inter|) / |union|``; ``|union| = 0`` gives 1 for every tau.

Rendering is not done here: the caller passes the estimated and GT depth renders (our batched
renderer makes them). Both masks need ``d_model > 0``, so a pixel outside both renders never enters
the union: a ``window`` covering both silhouettes gives exactly the full-image result.
"""

from __future__ import annotations

import numpy as np

#: VSD misalignment tolerance delta (mm) per dataset, eval_bop19_pose.py; every other dataset: 15 mm.
VSD_DELTAS: dict[str, float] = {"itodd": 5.0}
VSD_DEFAULT_DELTA = 15.0
#: VSD misalignment tolerances tau (fractions of the diameter), with np.arange's float noise kept on
#: purpose: 0.15000000000000002 and 0.35000000000000003, as the toolkit passes them.
VSD_TAUS: np.ndarray = np.arange(0.05, 0.51, 0.05)

#: ``(y0, x0, y1, x1)``: rows y0..y1-1 and columns x0..x1-1 of the full image.
Window = tuple[int, int, int, int]


def vsd_delta(dataset: str) -> float:
    """The BOP'19 VSD delta (mm) for a dataset name: 5 for ITODD, 15 otherwise (DIMO included)."""
    return VSD_DELTAS.get(dataset, VSD_DEFAULT_DELTA)


def vsd(
    depth_test: np.ndarray,
    depth_est: np.ndarray,
    depth_gt: np.ndarray,
    K: np.ndarray,
    delta: float,
    taus: np.ndarray | list[float] = VSD_TAUS,
    diameter: float | None = None,
    normalized_by_diameter: bool = True,
    *,
    window: Window | None = None,
) -> np.ndarray:
    """VSD errors ``(len(taus),)`` of one estimate against one GT instance.

    Args:
        depth_test: test depth image (mm, 0 = missing), the full ``(H, W)`` image or already cut to ``window``.
        depth_est, depth_gt: depth renders (mm, 0 = background) of the model in the estimated and the
            GT pose, full size or cut to ``window``. Cast to float32, the toolkit's depth type.
        K: ``(3, 3)`` intrinsics of the full image.
        delta: visibility tolerance (mm), see :func:`vsd_delta`.
        taus: misalignment tolerances (fractions of the diameter if normalised, else mm).
        diameter: object diameter (mm); required when ``normalized_by_diameter``.
        normalized_by_diameter: divide the per-pixel distances by ``diameter`` (BOP'19: True).
        window: ``(y0, x0, y1, x1)`` of the full image where the arrays lie (or are cut); must
            contain every non-zero pixel of both renders, and then the result equals the full image's.

    Returns:
        float64 errors in [0, 1], one per tau.
    """
    if normalized_by_diameter and diameter is None:
        raise ValueError("vsd: diameter is required when normalized_by_diameter is True")
    taus = np.asarray(taus, dtype=np.float64).reshape(-1)
    delta = float(delta)  # a Python float, like the toolkit's parsed delta: compared in float32 below
    origin = (0, 0) if window is None else (int(window[0]), int(window[1]))
    d_test, d_est, d_gt = (
        _cut(d, window, name)
        for d, name in ((depth_test, "depth_test"), (depth_est, "depth_est"), (depth_gt, "depth_gt"))
    )
    if not d_test.shape == d_est.shape == d_gt.shape:
        raise ValueError(f"vsd: depth shapes differ: test {d_test.shape}, est {d_est.shape}, gt {d_gt.shape}")
    dist_test = depth_to_distance(d_test, K, origin=origin)
    dist_est = depth_to_distance(d_est, K, origin=origin)
    dist_gt = depth_to_distance(d_gt, K, origin=origin)

    test32 = dist_test.astype(np.float32)
    test_missing = dist_test == 0
    visib_gt = ((dist_gt.astype(np.float32) - test32 <= delta) | test_missing) & (dist_gt > 0)
    est_present = dist_est > 0
    visib_est = (((dist_est.astype(np.float32) - test32 <= delta) | test_missing) & est_present) | (
        visib_gt & est_present
    )

    inter = visib_gt & visib_est
    union_count = int(np.count_nonzero(visib_gt | visib_est))
    if union_count == 0:
        return np.ones(len(taus))
    comp_count = union_count - int(np.count_nonzero(inter))
    dists = np.abs(dist_gt[inter] - dist_est[inter])
    if normalized_by_diameter:
        dists /= diameter
    costs = np.count_nonzero(dists[None, :] >= taus[:, None], axis=1)  # cost "step": equality is a miss
    return (costs + comp_count) / float(union_count)


def depth_to_distance(depth: np.ndarray, K: np.ndarray, origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """Distance image ``(H, W)`` float64 (mm from the camera centre) from a depth image ``(H, W)``.

    ``dist = sqrt(((x - cx) / fx * d)^2 + ((y - cy) / fy * d)^2 + d^2)`` with x, y the INTEGER
    column/row of the pixel in the full image (``origin = (row, column)`` of ``depth[0, 0]``), and
    0 where the depth is 0. This is the BOP toolkit's ``depth_im_to_dist_im_fast`` quirk (no +0.5):
    the one place in bop-cender that does not use pixel centres (u + 0.5, v + 0.5), copied so that
    VSD matches the official numbers. The operations are in the toolkit's order and precision.
    """
    depth = np.asarray(depth)
    K = np.asarray(K, dtype=np.float64)
    h, w = depth.shape
    xs = np.arange(origin[1], origin[1] + w)
    ys = np.arange(origin[0], origin[0] + h)
    pre_x = (xs - K[0, 2]) / np.float64(K[0, 0])  # (W,) float64
    pre_y = (ys - K[1, 2]) / np.float64(K[1, 1])  # (H,)
    return np.sqrt(
        np.multiply(pre_x[None, :], depth) ** 2
        + np.multiply(pre_y[:, None], depth) ** 2
        + depth.astype(np.float64) ** 2
    )


def overlapping_sphere_projections(radius: float, t_est: np.ndarray, t_gt: np.ndarray) -> np.ndarray:
    """The toolkit's VSD early-out test (``misc.overlapping_sphere_projections``), vectorised.

    Centres projected on the z = 1 plane are compared with ``radius (1/z_e + 1/z_g)``; False (VSD = 1
    for every tau without rendering) when they are at least that far apart or either z is 0.

    Args:
        radius: half the object diameter, mm.
        t_est, t_gt: ``(E, 3)`` or ``(3,)`` sphere centres (the pose translations), mm.

    Returns:
        ``(E,)`` bool (``(1,)`` for single centres).
    """
    p1 = np.asarray(t_est, dtype=np.float64).reshape(-1, 3)
    p2 = np.asarray(t_gt, dtype=np.float64).reshape(-1, 3)
    p1, p2 = np.broadcast_arrays(p1, p2)
    valid = (p1[:, 2] != 0) & (p2[:, 2] != 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        proj1 = p1[:, :2] / p1[:, 2:3]
        proj2 = p2[:, :2] / p2[:, 2:3]
        diff = proj1 - proj2
        proj_dist = np.sqrt(diff[:, 0] * diff[:, 0] + diff[:, 1] * diff[:, 1])
        thresh = radius * (1.0 / p1[:, 2] + 1.0 / p2[:, 2])
        return valid & (proj_dist < thresh)


def _cut(depth: np.ndarray, window: Window | None, name: str) -> np.ndarray:
    """``depth`` as float32, sliced to ``window`` unless it already has the window's shape."""
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise ValueError(f"vsd: {name} must be a 2D depth image, got shape {depth.shape}")
    depth = depth.astype(np.float32, copy=False)
    if window is None:
        return depth
    y0, x0, y1, x1 = (int(v) for v in window)
    if not (0 <= y0 < y1 and 0 <= x0 < x1):
        raise ValueError(f"vsd: window {window} must be (y0, x0, y1, x1) with 0 <= y0 < y1 and 0 <= x0 < x1")
    if depth.shape == (y1 - y0, x1 - x0):
        return depth
    if depth.shape[0] < y1 or depth.shape[1] < x1:
        raise ValueError(
            f"vsd: {name} of shape {depth.shape} is neither the window's {(y1 - y0, x1 - x0)} nor contains it"
        )
    return depth[y0:y1, x0:x1]
