"""The scene cost's torch steps: how well a whole placement, all parts rendered together, explains the target edges.

Forward, the paper's cost of the composite (its rendered curvature edges to the nearest target edge); backward, every
target edge pixel to the nearest edge the composite draws. The sweeps' acceptance and the scene polish judge by it
(:meth:`~bop_cender.pose.backend.Backend.scene_cost` chooses these torch steps or the compiled ones).

A one-object two-sided judge (the target edges inside a pose's own silhouette it leaves unexplained) was measured and
removed: no gain as the judge of the search alone (``results/accuracy/README.md``, "Stage-3 settings: how each
default was measured", ``coverage_weight``).
"""

from __future__ import annotations

import torch

from bop_cender.pose.cost import distance_maps, view_costs
from bop_cender.render.curvature import curvature


def torch_scene_cost(normals: torch.Tensor, dist_maps: torch.Tensor, target_edges: torch.Tensor,
                     edge_threshold: float) -> float:  # fmt: skip
    """The scene cost (:meth:`~bop_cender.pose.backend.Backend.scene_cost`) of a composite's full-frame
    ``normals (V, H, W, 3)`` by torch operators: the mean over the V views of forward (the paper's cost of the
    composite against ``dist_maps (V, H, W)``) plus backward (every ``target_edges (V, H, W)`` pixel's distance to the
    nearest edge the composite draws, its curvature above ``edge_threshold``), in pixels.

    Why both terms: a part moved onto a neighbour's edges costs itself no more forward, but the edges of its true place
    are now explained by nothing and cost the scene backward; a part removed or hidden does too. (Only the target edges
    inside the composite's silhouette, as the removed two-sided judge counted them, would miss exactly those: a scene
    without one of its parts cost less than the full true scene.) Target edges of parts never detected add the same to every
    placement compared. A view where the composite draws no edge costs the image diagonal forward.
    """
    V = int(normals.shape[0])
    offsets = torch.zeros((V, 2), dtype=torch.int64, device=normals.device)
    curv = curvature(normals)  # (V, H, W)
    forward = view_costs(curv, dist_maps, offsets)
    backward = mean_distance_to_own_edges(curv, target_edges, edge_threshold)
    return float((forward + backward).mean())


def mean_distance_to_own_edges(curv: torch.Tensor, pixels: torch.Tensor, edge_threshold: float) -> torch.Tensor:
    """``(N,)``: the mean distance (pixels) from the ``pixels (N, H, W)`` (bool) of each canvas to the canvas's own
    edges (``curv (N, H, W)`` above ``edge_threshold``); 0 where no pixel is given."""
    own_dist = torch.as_tensor(distance_maps((curv > edge_threshold).cpu().numpy()), device=curv.device)
    count = pixels.sum((1, 2))
    return torch.where(count > 0, (own_dist * pixels).sum((1, 2)) / count.clamp_min(1), 0.0)
