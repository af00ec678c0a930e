"""The centre term (ours, ``poses.center_weight``): how far a pose's centre strays from where stage 2 found it.

Every cost of the search, the sweeps' judge and the scene polish add it, so that a part is not pulled onto a
neighbour's edges away from its detected 3D centre; the center heatmap's own sharpness scales it by how sure the
centre is (figures: ``results/accuracy/README.md``, "Stage-3 settings", ``poses.center_weight``).
"""

from __future__ import annotations

import numpy as np

from bop_cender.geometry.sampling import sample_scores
from bop_cender.pose.types import SceneCameras


def center_term(
    T_world_model: np.ndarray,
    center_model: np.ndarray,
    view_scores: np.ndarray | None,
    center_map: np.ndarray | None,
    weights: np.ndarray,
    cameras: SceneCameras,
    center_weight: float,
) -> np.ndarray:
    """``(n,)`` the centre term of poses ``(n, 4, 4)`` of one object (pixels).

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
