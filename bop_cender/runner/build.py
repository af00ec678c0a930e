"""The method of a request: its dataset opened, its network weights read and checked, its heatmap source built.

Every process that runs scenes (the run's own, or each worker of ``--workers``) builds its method from the request
with these functions, and reads the weights file once: the run's process reads it for its checks before any scene
(:func:`read_weights`) and builds its method, and the shards' fingerprint, from the same object; a worker reads it
once for all its scenes.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from bop_cender.data.types import Dataset
from bop_cender.errors import ConfigError
from bop_cender.meshes import MeshCache
from bop_cender.method import CenDerNet, network_curvature_choice
from bop_cender.runner.request import RunRequest, check_source, resolve_weights, uses_network

if TYPE_CHECKING:  # the network code loads only where a run uses a network
    from bop_cender.net.weights import NetWeights


def open_run_dataset(request: RunRequest) -> Dataset:
    """The dataset of ``request``: its split grouped in views per scene (``n_views``, ``seed``), its models."""
    from bop_cender.data.registry import DatasetRequest
    from bop_cender.datasets import open_with_demo

    data = DatasetRequest(
        request.dataset, request.data_root, request.split, request.n_views, request.seed, request.model_type
    )
    return open_with_demo(data)  # no data root: the embedded demo, silently


def build_method(
    request: RunRequest, dataset: Dataset, cost_threads: int = 1, weights: NetWeights | None = None
) -> CenDerNet:
    """The method for a request: oracle heatmaps, the network (given or shipped weights), or one head of each.

    ``weights``: the request's network weights as :func:`read_weights` gave them (None: read here where a network
    is used), so that a process that has read them for its checks does not read the file again."""
    from bop_cender.net.mixed import MixedPredictor
    from bop_cender.net.oracle import OraclePredictor

    check_source(request.heatmaps)
    meshes = MeshCache(dataset.models)
    if request.heatmaps == "oracle":
        predictor = OraclePredictor(dataset.models, meshes, request.config.targets, device=request.device)
    else:
        predictor = net = net_predictor(request, dataset, weights)
        if request.heatmaps != "net":  # one head of each; the oracle's centre channels follow the network's
            oracle = OraclePredictor(
                dataset.models, meshes, request.config.targets, net.channel_obj_ids, device=request.device
            )
            oracle_centers = request.heatmaps == "oracle-centers"
            predictor = MixedPredictor(oracle, net) if oracle_centers else MixedPredictor(net, oracle)
    return CenDerNet(
        dataset.models, request.config, predictor, meshes, cost_threads=cost_threads, pose_device=request.pose_device
    )


def method_for(request: RunRequest) -> tuple[RunRequest, Dataset, CenDerNet]:
    """The request with its weights resolved, its dataset and its method: what a script that runs scenes through the
    method by hand needs (``scripts/centre_placement.py``, ``scripts/centre_families.py``)."""
    request = resolve_weights(request)
    dataset = open_run_dataset(request)
    return request, dataset, build_method(request, dataset)


def read_weights(request: RunRequest, dataset: Dataset) -> NetWeights:
    """The network weights of ``request`` (given or shipped), read from their file and checked against the dataset and
    the config: what a process reads once and builds its method with (:func:`build_method`).

    Raises:
        ConfigError: an unreadable file, weights for another dataset kind, center channels that miss a target
            object of the dataset, or targets (curvature scale) other than the config's.
    """
    from bop_cender.net.weights import check_covers_targets, load_weights

    weights = load_weights(resolve_weights(request).weights, dataset=request.dataset)
    check_covers_targets(weights, dataset.models)
    if weights.targets.curvature_scale != request.config.targets.curvature_scale:
        raise ConfigError(
            f"the weights were trained on curvature / {weights.targets.curvature_scale:g}; this run's config says"
            f" / {request.config.targets.curvature_scale:g} (--set targets.curvature_scale=...)",
            file=weights.path,
        )
    return weights


def net_predictor(request: RunRequest, dataset: Dataset, weights: NetWeights | None = None):
    """The network predictor of ``request`` (weights resolved), checked against the dataset and the config.

    ``weights``: as :func:`read_weights` gave them for this request and dataset (None: read here).

    Raises:
        ConfigError: see :func:`read_weights`.
    """
    from bop_cender.net.predictor import NetPredictor

    weights = read_weights(request, dataset) if weights is None else weights
    return NetPredictor(
        weights,
        device=request.device,
        known_object_ids=request.config.known_object_ids,
        curvature_threshold=network_threshold(request, weights)[0],
    )


def network_threshold(request: RunRequest, weights: NetWeights) -> tuple[float | None, str]:
    """:func:`~bop_cender.method.network_curvature_choice` for a run on ``request.split`` with ``weights``
    (:class:`~bop_cender.net.weights.NetWeights`): the split's own calibration where the weights carry one."""
    return network_curvature_choice(request.config, *weights.curvature_threshold_for(request.split))


def curvature_threshold(request: RunRequest, weights: NetWeights | None) -> tuple[float, str]:
    """Where stage 3 binarises the curvature of ``request``'s heatmaps, and which setting says so (for the sidecar
    and the summary): a network's curvature at ``poses.network.t_b`` or the weights' calibration, else ``t_b``.
    ``weights``: the request's, from :func:`read_weights` (None where no network is used)."""
    if not uses_network(request.heatmaps) or request.heatmaps == "oracle-curvature":
        return request.config.poses.t_b, "poses.t_b"
    assert weights is not None, "a network's curvature needs its weights"
    value, source = network_threshold(request, weights)
    return (request.config.poses.t_b if value is None else value), source
