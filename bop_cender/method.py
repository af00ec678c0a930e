"""CenDerNet as a BOP method: heatmaps -> 3D centres -> poses, for one scene at a time.

``CenDerNet(models, config, predictor).estimate(scene)`` returns a :class:`SceneEstimate` (world-frame
poses, one per detected object, BOP score = ``1 / (1 + cost)``: higher is better, so BOP's top-n
ranking keeps the best-fitting estimates) with per-stage timings; :meth:`CenDerNet.run_scene` also
returns what each stage produced (heatmaps, centres, placed objects) for figures and diagnostics.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Protocol

import numpy as np
import torch

from bop_cender.centers import Center3D, CenterConfig, detect_centers, sample_scores
from bop_cender.data.canvas import on_one_canvas
from bop_cender.data.types import ObjectModel, Scene
from bop_cender.errors import ConfigError
from bop_cender.estimates import ObjectEstimate, SceneEstimate
from bop_cender.meshes import MeshCache
from bop_cender.net.heatmaps import Heatmaps
from bop_cender.net.targets import INDUSTRIAL_TARGETS, TargetConfig
from bop_cender.pose.config import PRESETS, PoseConfig
from bop_cender.pose.config_names import ALSO, FIGURES, REMOVED, RENAMED
from bop_cender.pose.context import scene_context
from bop_cender.pose.sweeps import optimise_scene
from bop_cender.pose.types import PlacedObject, PoseTarget, SceneCameras
from bop_cender.settings import apply_setting


class HeatmapPredictor(Protocol):
    """Anything that turns a scene's views into :class:`Heatmaps` (the network, the oracle)."""

    name: str

    def predict(self, scene: Scene) -> Heatmaps: ...


@dataclass(frozen=True)
class CenDerNetConfig:
    """Every setting of the method (the paper's defaults; see each stage's config for what is ours).

    Attributes:
        targets: how GT heatmaps are made (the oracle; the network's training targets).
        centers: stage 2.
        poses: stage 3.
        preset: the named starting point :meth:`for_dataset` made this config from (``ours``; ``paper``: the paper's
            stage 3, :data:`~bop_cender.pose.config.PRESETS`), recorded with the run; the settings themselves are in
            the sections.
        known_counts: prune the centres to the known number of objects per channel (paper: "if
            information about the number of objects in the scene is available": DIMO ``scene_info``,
            BOP's targets). The count comes from the scene's annotations of target objects.
        known_object_ids: with one shared center channel, try only the object ids the scene is known to
            hold (DIMO's compositions name the part type) instead of every target id of the dataset; with a
            factored network (``tless-factored``), restrict its class softmax to them (BOP's targets name them).
    """

    targets: TargetConfig = field(default_factory=TargetConfig)
    centers: CenterConfig = field(default_factory=CenterConfig)
    poses: PoseConfig = field(default_factory=PoseConfig)
    known_counts: bool = True
    known_object_ids: bool = True
    preset: str = "ours"

    def __post_init__(self) -> None:
        if self.preset not in PRESETS:
            raise ConfigError(f"unknown preset {self.preset!r}; known: {', '.join(PRESETS)}", field="--preset")

    @staticmethod
    def for_dataset(name: str, preset: str = "ours") -> CenDerNetConfig:
        """The settings for ``name`` (``dimo``; ``tless`` / ``bop``) from ``preset`` (:data:`PRESETS`: ``ours`` or
        ``paper``, the paper's stage 3).

        Stage 3 differs by layout (:data:`LAYOUT_SETTINGS`): the edge search's screen (``poses.screen.starts``) is
        off for T-LESS / BOP layouts (measured with oracle heatmaps on T-LESS seed 4243: AR 0.893 without, 0.881 with
        8 screened starts; on DIMO layouts it helps, ``results/accuracy/README.md``). Bin-picking piles
        (``industrial`` and the BOP-Industrial names) keep the screen and keep the starts apart modulo each part's
        symmetries (``poses.candidates.symmetric_separation``): oracle bop25_mAP 0.893 / 0.804 / 0.836 -> 0.922 /
        0.833 / 0.855 on three synthetic bin sets (``results/accuracy/industrial/README.md``, session 27)."""
        if preset not in PRESETS:
            raise ConfigError(f"unknown preset {preset!r}; known: {', '.join(PRESETS)}", field="--preset")
        layout = LAYOUT_SETTINGS.get(name, ["poses.screen.starts=0"])
        config = CenDerNetConfig(targets=TargetConfig.for_dataset(name), preset=preset)
        return config.with_settings([*layout, *(f"poses.{s}" for s in PRESETS[preset])])

    def as_dict(self) -> dict:
        return asdict(self)

    def for_task(self, task: str) -> CenDerNetConfig:
        """The settings for a BOP task: ``localization`` as they are; ``detection`` (BOP'24/'25) without the instance
        counts and object ids of the scene (the task gives neither), ``known_counts`` and ``known_object_ids`` false."""
        return self if task == "localization" else replace(self, known_counts=False, known_object_ids=False)

    def with_settings(self, settings: Sequence[str]) -> CenDerNetConfig:
        """A copy with ``path=value`` settings applied at any depth (``poses.t_b=0.5``, ``poses.candidates.n=500``,
        ``centers.d_c=30``, ``known_counts=false``), each value parsed as its field's type
        (:func:`~bop_cender.settings.apply_setting`).

        Raises:
            ConfigError: unknown, renamed or removed setting (the message names the new one, or why it was removed
                and where its figures are), or a value that is not of the field's type or out of its range.
        """
        config = self
        for item in settings:
            if item.partition("=")[0].strip() == "preset":
                raise ConfigError("the preset is chosen before any setting (run --preset ours|paper)", field="--set")
            config = apply_setting(config, item, _RENAMED, _REMOVED, _ALSO)
        return config


#: Stage 3's settings per layout that differ from the defaults (:meth:`CenDerNetConfig.for_dataset`); any other
#: layout: T-LESS / BOP's, the screen off.
LAYOUT_SETTINGS: dict[str, list[str]] = {
    "dimo": [],
    **{name: ["poses.candidates.symmetric_separation=true"] for name in sorted(INDUSTRIAL_TARGETS)},
}


#: Old ``--set`` names -> new ones, and removed options -> why (stage 3's: :mod:`bop_cender.pose.config_names`).
_RENAMED = {f"poses.{old}": f"poses.{new}" for old, new in RENAMED.items()}
_ALSO = {f"poses.{old}": note for old, note in ALSO.items()}
_REMOVED = {
    **{f"poses.{name}": f"{why}; figures: {FIGURES}" for name, why in REMOVED.items()},
    "test_flips": "averaging the network's passes lost end to end with both shipped networks (DIMO 0.870 -> 0.834,"
    f" T-LESS AR 0.355 -> 0.328; heatmaps --test-flips keeps it for the 2D figures); figures: {FIGURES}",
}


@dataclass(frozen=True, eq=False)
class SceneOutput:
    """Everything one scene went through: the estimate and each stage's output."""

    estimate: SceneEstimate
    heatmaps: Heatmaps
    centers: list[Center3D]
    placed: list[PlacedObject]


class CenDerNet:
    """The three stages composed (docs/design.md, "The data flow": ``CenDerNet.estimate(scene) -> SceneEstimate``)."""

    def __init__(
        self,
        models: Mapping[int, ObjectModel],
        config: CenDerNetConfig,
        predictor: HeatmapPredictor,
        meshes: MeshCache | None = None,
        cost_threads: int = 1,
        pose_device: str | torch.device | None = "cpu",
    ) -> None:
        """``cost_threads``: threads for the candidates' cost (see :func:`~bop_cender.pose.context.scene_context`).

        ``pose_device``: where stage 3 renders and costs (None: the device of the heatmaps). The CPU by default,
        whatever device the heatmaps come from: on an H200 machine the pose stage of three DIMO scenes took 14.0,
        13.1 and 34.0 s on CUDA (``results/bench/run_*nvidia-h200.md``), against 8.7, 9.0 and 17.9 s on 2 CPU
        cores (``results/bench/run_amd-epyc-2cores.md``; 3.9, 8.8 and 13.9 s on a 2-core Intel Xeon since stage 3's
        CPU loops are compiled, ``results/bench/run_intel-*``): its batches are small (a Nelder-Mead step costs 1 to 8
        poses), so a cost call is bound by its ~730 kernel launches and ~77 host synchronisations (1.3 ms of GPU
        work in a 24 ms call), not by the GPU."""
        self.cost_threads = cost_threads
        self.pose_device = pose_device
        self.models = models
        self.config = config
        self.predictor = predictor
        self.meshes = meshes or MeshCache(models)

    def estimate(self, scene: Scene) -> SceneEstimate:
        return self.run_scene(scene).estimate

    def run_scene(self, scene: Scene) -> SceneOutput:
        """Run the three stages on ``scene`` and time each (a capture of cameras of several sizes seen at one,
        :func:`~bop_cender.data.canvas.on_one_canvas`; the estimate is in the world frame, so any view's camera
        writes its rows)."""
        scene = on_one_canvas(scene)
        t0 = time.perf_counter()
        heatmaps = self.predictor.predict(scene)
        t1 = time.perf_counter()
        Ks = np.stack([v.K for v in scene.views])
        T_cw = np.stack([v.T_cam_world for v in scene.views])
        counts = self._known_counts(scene, heatmaps) if self.config.known_counts else None
        center_maps = heatmaps.center.detach().cpu().numpy()  # (V, C, H, W)
        centers = detect_centers(
            center_maps, Ks, T_cw, self.config.centers, heatmaps.channel_obj_ids, counts, heatmaps.exclusive_channels
        )
        t2 = time.perf_counter()
        candidate_ids = self._candidate_ids(scene)
        targets = [
            PoseTarget(
                c.position,
                c.view_scores,
                (c.obj_id,) if c.obj_id is not None else candidate_ids,
                center_maps[:, c.channel],
            )
            for c in centers
        ]
        H, W = heatmaps.size
        placed = []
        if targets and candidate_ids:
            context = scene_context(
                heatmaps.curvature,
                SceneCameras(Ks, T_cw, H, W),
                self.meshes,
                lambda obj_id: self.models[obj_id].center,
                self.config.poses.for_network_centers() if heatmaps.centers_from_network else self.config.poses,
                cost_threads=self.cost_threads,
                curvature_scale=self.config.targets.curvature_scale,
                target_threshold=self._curvature_threshold(heatmaps),
                device=self.pose_device,
                symmetries=lambda obj_id: self.models[obj_id].symmetry_transforms()[0],
            )
            placed = optimise_scene(context, targets)
        t3 = time.perf_counter()
        objects = tuple(
            ObjectEstimate(p.obj_id, p.T_world_model, 1.0 / (1.0 + p.cost), self._image_scores(p, heatmaps, Ks, T_cw))
            for p in placed
        )
        timings = {"heatmaps": t1 - t0, "centers": t2 - t1, "poses": t3 - t2}
        estimate = SceneEstimate(scene.key, scene.scene_id, objects, time_s=t3 - t0, timings=timings)
        return SceneOutput(estimate, heatmaps, centers, placed)

    def _curvature_threshold(self, heatmaps: Heatmaps) -> float | None:
        """Where stage 3 binarises ``heatmaps``' curvature: a network's (heatmaps that carry a threshold) at
        ``poses.network.t_b`` when set, else at the threshold they carry; None (``t_b``) for the oracle's."""
        if heatmaps.curvature_threshold is None:
            return None
        return network_curvature_choice(self.config, heatmaps.curvature_threshold)[0]

    def _image_scores(self, placed: PlacedObject, heatmaps: Heatmaps, Ks: np.ndarray, T_cw: np.ndarray) -> dict:
        """Per image, the center heatmap at the projection of the placed object's centre (in [0, 1]): how
        well that image shows it, so that BOP's per-image top-n prefers the objects an image shows."""
        center = placed.T_world_model[:3, :3] @ self.models[placed.obj_id].center + placed.T_world_model[:3, 3]
        maps = heatmaps.center[:, heatmaps.channel_of(placed.obj_id)].detach().cpu().numpy()
        scores = np.clip(sample_scores(center[None], maps, Ks, T_cw)[0], 0.0, 1.0)
        return {im_id: float(s) for im_id, s in zip(heatmaps.im_ids, scores, strict=True)}

    def _known_counts(self, scene: Scene, heatmaps: Heatmaps) -> dict[int, int]:
        counts = Counter(g.obj_id for g in scene.gt if g.obj_id in self.models and self.models[g.obj_id].is_target)
        if heatmaps.channel_obj_ids is None:
            return {0: sum(counts.values())}
        return {c: counts.get(obj_id, 0) for c, obj_id in enumerate(heatmaps.channel_obj_ids)}

    def _candidate_ids(self, scene: Scene) -> tuple[int, ...]:
        targets = sorted(i for i, m in self.models.items() if m.is_target)
        if self.config.known_object_ids:
            known = sorted({g.obj_id for g in scene.gt if g.obj_id in targets})
            if known:
                return tuple(known)
        return tuple(targets)


def network_curvature_choice(
    config: CenDerNetConfig, calibrated: float | None, calibrated_for: str | None = None
) -> tuple[float | None, str]:
    """Where stage 3 binarises a network's curvature, the precedence in one place: ``poses.network.t_b``, else the
    weights' calibration ``calibrated`` (made on views of split ``calibrated_for``, None: the general one; see
    :meth:`~bop_cender.net.weights.NetWeights.curvature_threshold_for`), else None (stage 3's ``t_b``); with the
    name of the setting that decided (for the run's sidecar and summary)."""
    if config.poses.network.t_b is not None:
        return config.poses.network.t_b, "poses.network.t_b"
    if calibrated is not None:
        return calibrated, "the weights' calibration" + (f" on {calibrated_for} views" if calibrated_for else "")
    return None, "poses.t_b: the weights carry no calibrated threshold"
