"""Training stage 1 (``bop-cender train``): the U-Net on a split's views and their cached GT heatmaps.

- Loss: BCE-with-logits on the center and on the curvature heatmaps, summed (paper Section 2.1).
- Adam, learning rate 3e-4 (paper appendix), batch size and epochs from the config.
- Every epoch: the appendix's augmentations (:mod:`bop_cender.net.augment`), optionally random crops
  (the net is fully convolutional: crops cut the cost of large T-LESS images), then validation on
  ``val_split`` (losses, center-peak precision / recall / F1, curvature AP and F1 at t_b, and the curvature
  threshold with the best F1, stored in the weights as their calibrated ``curvature_threshold``: stage 3
  binarises this network's curvature there, ``poses.network.t_b``).
- Deterministic per seed on the CPU: the model's initial weights come from ``seed``, the order of the
  samples, the augmentations and the crops of epoch ``e`` from ``(seed, e)`` alone, so that a run
  resumed from its checkpoint after epoch ``e`` continues bit for bit as if it had never stopped.
- ``RUN_DIR/checkpoint.pt`` (model, optimiser, epoch, history; atomic) and ``RUN_DIR/weights.pt`` (the
  latest weights alone, what ``run --weights`` takes) after every epoch; ``RUN_DIR/metrics.csv`` one row
  per epoch; ``RUN_DIR/config.json`` the run's config. ``RUN_DIR`` and its files appear with the first finished
  epoch: a run that stops before it leaves nothing in ``--out``.
"""

from __future__ import annotations

import csv
import io
import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from bop_cender.data.bop_io import check_output_dir, write_text_atomic
from bop_cender.data.industrial import config_layout
from bop_cender.data.registry import DatasetRequest, open_dataset
from bop_cender.errors import BopCenderError, ConfigError
from bop_cender.meshes import MeshCache
from bop_cender.net.augment import AugmentConfig, augment_with_votes
from bop_cender.net.camera_augment import camera_augment
from bop_cender.net.init_from import start_from
from bop_cender.net.metrics import HeatmapMetrics, HeatmapMetricsConfig
from bop_cender.net.predictor import known_class_mask
from bop_cender.net.samples import SampleSet, load_samples
from bop_cender.net.targets import TargetConfig
from bop_cender.net.unet import UNet, UNetSpec, factored_center_logits
from bop_cender.net.votes import vote_loss
from bop_cender.net.weights import CURVATURE_THRESHOLD, load_weights, save_weights, weights_kind, weights_payload
from bop_cender.progress import progress_bar

CENTER_LOSSES = ("bce", "focal")


@dataclass(frozen=True)
class TrainConfig:
    """One training run (saved as ``RUN_DIR/config.json``; a resumed run must have the same).

    Attributes:
        dataset, data_root, split: the training data (``dimo`` / ``tless`` / ``bop``).
        val_split, val_data_root: validation data (default root: the training root); None: no validation.
        epochs, batch_size, lr: optimisation (paper: Adam 3e-4; DIMO 200 epochs of 8, T-LESS 40 of 4).
        variant, width: network variant (:meth:`UNetSpec.named`) and width multiplier.
        crop: ``(H, W)`` random crops of every sample (None: whole images).
        augment: the appendix's augmentations (False: none, for tests and ablations).
        camera_augment: after them, another camera per sample (:mod:`bop_cender.net.camera_augment`: colour cast,
            tone curve, defocus, resolution loss, signal-dependent noise, grey), drawn from its own stream so that
            the appendix's draws stay those of a run without it (issue 42's lever, measured in
            ``results/robustness/``).
        seed: everything random derives from it.
        limit_scenes, val_limit_scenes: the first K scenes only (smoke runs).
        init_weights: start from these weights (same network spec) instead of a random init: fine-tuning,
            e.g. a few epochs at a lower learning rate after a run (the optimiser starts afresh). Weights of a
            network without context convolutions or a refinement may start a run of the same network with them
            (``dimo-lean`` -> ``dimo-context`` -> ``dimo-refine``): the new convolutions start as the identity.
        center_pos_weight: ``w`` of the center loss's per-pixel weight ``1 + w * target`` (0: the paper's plain
            BCE). Not in the paper: with one channel per object id (T-LESS: 30) nearly every center pixel is
            background, and plain BCE keeps every center map near 0 for many epochs on our CPU budget
            (measured: a maximum of 0.016 after 3 epochs of 768 views); weighting the blobs makes them rise.
        center_loss: ``bce`` (the paper's BCE-with-logits, weighted by ``center_pos_weight``) or ``focal``
            (ours, :func:`center_focal_loss`: CenterNet's penalty-reduced focal loss, normalised by the number
            of blobs). Plain BCE learns a blob's expected value: where the network is unsure of a centre by a
            few pixels the map becomes a smeared cloud whose peak falls under stage 2's threshold (the
            shipped BCE network: 3D centres within 5 mm for 24 of 70 parts of a test set); the focal loss
            rewards the peak pixel alone and forgives near misses, so the maps keep one sharp peak per part.
        center_loss_weight: the center loss's weight in the sum with the curvature BCE (the backbone is
            shared: the focal loss, normalised by a handful of blobs per image, is far larger than a per-pixel
            mean and would otherwise drive the shared features alone).
        class_loss_weight: for a network with factored centers (``tless-factored``): the weight of the
            per-pixel object-class cross-entropy (:func:`center_class_loss`); the center loss then applies to
            the class-agnostic center logit against the max over the channels' targets.
        factored_centers: give ``variant`` a factored center head (``tless-factored`` has one already): the
            paper's ``tless`` network with it is the recipe for a GPU run (``--variant tless --factored-centers``).
        train_only: names of the network's top-level modules (:meth:`UNet.named_children`: ``e1`` ... ``d1``,
            ``context``, ``center_head``, ``curvature_head``, ``refine``) whose parameters train; every other
            module is frozen, its batch-norm statistics too (kept in eval mode), so it computes exactly what
            it did. Empty: everything trains. Why: a refinement added to a trained network
            (``--init-weights``, ``dimo-refine`` from ``dimo-context``) trained together with the shared
            backbone moved the centre features (validation centre F1 0.787 -> 0.722 while curvature AP rose
            0.595 -> 0.705, ``results/net/dimo.md``); ``refine,curvature_head`` leaves the centres as they were.
        center_votes: give ``variant`` a vote head (``dimo-votes`` and ``tless-votes`` have one): e.g. the paper's
            networks with votes for a GPU run (``--variant tless --factored-centers --center-votes``).
        vote_loss_weight: for a network with a vote head (``dimo-votes``, ``tless-votes``): the weight of
            :func:`~bop_cender.net.votes.vote_loss` in the sum (ours: 1; its three terms are means of order 0.1-1).
    """

    dataset: str
    data_root: str | None = None
    split: str = "train"
    val_split: str | None = None
    val_data_root: str | None = None
    epochs: int = 10
    batch_size: int = 8
    lr: float = 3e-4
    variant: str = "dimo-lean"
    width: float = 1.0
    crop: tuple[int, int] | None = None
    augment: bool = True
    camera_augment: bool = False
    seed: int = 0
    limit_scenes: int | None = None
    val_limit_scenes: int | None = None
    init_weights: str | None = None
    center_pos_weight: float = 0.0
    center_loss: str = "bce"
    center_loss_weight: float = 1.0
    class_loss_weight: float = 0.1
    factored_centers: bool = False
    train_only: tuple[str, ...] = ()
    center_votes: bool = False
    vote_loss_weight: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "train_only", tuple(self.train_only))
        if len(set(self.train_only)) != len(self.train_only) or any(not n for n in self.train_only):
            raise ConfigError(
                f"expected distinct module names, got {','.join(self.train_only)!r}", field="--train-only"
            )
        for name in ("epochs", "batch_size"):
            if getattr(self, name) < 1:
                raise ConfigError(f"must be >= 1, got {getattr(self, name)}", field=f"--{name.replace('_', '-')}")
        if not (math.isfinite(self.lr) and self.lr > 0):
            raise ConfigError(f"must be a positive number, got {self.lr}", field="--lr")
        if not (math.isfinite(self.width) and self.width > 0):
            raise ConfigError(f"must be a positive number, got {self.width}", field="--width")
        if not (math.isfinite(self.center_pos_weight) and self.center_pos_weight >= 0):
            raise ConfigError(f"must be a number >= 0, got {self.center_pos_weight}", field="--center-pos-weight")
        if self.center_loss not in CENTER_LOSSES:
            raise ConfigError(
                f"expected one of {', '.join(CENTER_LOSSES)}, got {self.center_loss!r}", field="--center-loss"
            )
        if self.center_loss == "focal" and self.center_pos_weight != 0:
            raise ConfigError(
                "weights the BCE's blob pixels; the focal loss has none to weight", field="--center-pos-weight"
            )
        if not (math.isfinite(self.center_loss_weight) and self.center_loss_weight > 0):
            raise ConfigError(f"must be a positive number, got {self.center_loss_weight}", field="--center-loss-weight")
        if not (math.isfinite(self.class_loss_weight) and self.class_loss_weight > 0):
            raise ConfigError(f"must be a positive number, got {self.class_loss_weight}", field="--class-loss-weight")
        if not (math.isfinite(self.vote_loss_weight) and self.vote_loss_weight > 0):
            raise ConfigError(f"must be a positive number, got {self.vote_loss_weight}", field="--vote-loss-weight")
        if self.camera_augment and not self.augment:
            raise ConfigError("adds to the appendix's augmentations, which --no-augment turns off",
                              field="--camera-augment")  # fmt: skip
        if self.crop is not None and min(self.crop) < 1:
            raise ConfigError(f"crop sizes must be >= 1, got {self.crop}", field="--crop")
        if self.val_data_root is not None and self.val_split is None:
            raise ConfigError("validation data needs --val-split (which split of it to validate on)",
                              field="--val-data-root")  # fmt: skip
        for name in ("limit_scenes", "val_limit_scenes"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise ConfigError(f"must be >= 1, got {value}", field=f"--{name.replace('_', '-')}")

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["crop"] = None if self.crop is None else list(self.crop)
        d["train_only"] = list(self.train_only)
        return d

    def same_run_as(self, other: TrainConfig) -> bool:
        """Whether a checkpoint of ``other`` can be resumed under this config (more epochs allowed; the class loss's
        weight only matters to a factored variant)."""
        spec = self.network_spec()
        if not spec.factored_centers:
            other = replace(other, class_loss_weight=self.class_loss_weight)
        if not spec.center_votes:
            other = replace(other, vote_loss_weight=self.vote_loss_weight)
        return replace(self, epochs=other.epochs) == other

    def network_spec(self, center_channels: int | None = None) -> UNetSpec:
        """The run's network (:func:`network_spec_of`) with ``center_channels`` outputs; None: the dataset kind's
        (1 for DIMO, 2 standing for "one per object id" where only the architecture matters).

        Raises:
            ConfigError: a network that cannot be built (:func:`network_spec_of`).
        """
        if center_channels is None:
            center_channels = 1 if self.dataset == "dimo" else 2
        return network_spec_of(self.variant, self.width, center_channels, self.factored_centers, self.center_votes)


def network_spec_of(
    variant: str, width: float, center_channels: int, factored_centers: bool = False, center_votes: bool = False
) -> UNetSpec:
    """``variant`` at ``width`` with ``center_channels`` outputs, factored and with a vote head where asked (the CLI
    checks its flags with it before any data is read; :class:`TrainConfig` builds the run's network with it).

    Raises:
        ConfigError: a variant that does not fit the data's center channels (a factored head on one shared channel),
            or centre votes on one independent center channel per object id (their map is class-agnostic: only a
            factored head's channels share it).
    """
    try:
        spec = UNetSpec.named(variant, center_channels=center_channels, width=width)
    except ValueError as exc:
        raise ConfigError(f"{variant} cannot be built for this data ({exc})", field="--variant") from None
    if factored_centers and not spec.factored_centers:
        if center_channels < 2:
            raise ConfigError("needs one center channel per object id (T-LESS / BOP data)", field="--factored-centers")
        spec = replace(spec, factored_centers=True, name=f"{spec.name}+factored")
    if center_votes and not spec.center_votes:
        spec = replace(spec, center_votes=True, name=f"{spec.name}+votes")
    if spec.center_votes and spec.center_channels > 1 and not spec.factored_centers:
        raise ConfigError(
            "votes make one class-agnostic centre map: with one center channel per object id they need a factored"
            " center head (--factored-centers, or --variant tless-votes)",
            field="--center-votes",
        )
    return spec


@dataclass
class EpochRecord:
    """One row of ``metrics.csv``."""

    epoch: int
    train_loss: float
    train_center_loss: float
    train_curvature_loss: float
    images_per_s: float
    wall_s: float
    val: dict[str, float] = field(default_factory=dict)

    def row(self) -> dict[str, Any]:
        d = {k: v for k, v in asdict(self).items() if k != "val"}
        d.update({f"val_{k}": v for k, v in self.val.items()})
        return d


@dataclass(frozen=True)
class TrainSummary:
    run_dir: Path
    epochs_done: int
    resumed_from: int
    history: list[EpochRecord]
    wall_s: float


CHECKPOINT = "checkpoint.pt"
WEIGHTS = "weights.pt"
METRICS = "metrics.csv"
CONFIG = "config.json"


def train(
    config: TrainConfig,
    run_dir: str | Path,
    resume: bool = False,
    device: torch.device | str = "cpu",
    cache_dir: Path | None = None,
    progress: bool = True,
    announce: Callable[[str], None] | None = None,
) -> TrainSummary:
    """Train (or resume) a run; see the module docstring.

    Raises:
        ConfigError: ``run_dir`` holds another run (or a checkpoint without ``resume``), bad options.
        DatasetError: unreadable data.
    """
    say = announce or (lambda _msg: None)
    run_dir = Path(run_dir)
    check_output_dir(run_dir)
    checkpoint_path = run_dir / CHECKPOINT
    if checkpoint_path.exists() and not resume:
        raise ConfigError("holds a training run already: pass --resume to continue it, or another --out", file=run_dir)
    device = torch.device(device)
    kind = weights_kind(config.dataset)  # one channel, or one per object
    targets = TargetConfig.for_dataset(config_layout(config.dataset, config.data_root, config.split))
    votes = config.network_spec().center_votes
    train_set = _open_samples(
        config.dataset, config.data_root, config.split, config.limit_scenes, targets, cache_dir, progress, votes=votes
    )
    val_set = None
    if config.val_split is not None:
        val_root = config.val_data_root or config.data_root
        val_set = _open_samples(
            config.dataset, val_root, config.val_split, config.val_limit_scenes, targets, cache_dir, progress,
            channel_obj_ids=train_set.channel_obj_ids,
            flags=("--val-data-root" if config.val_data_root else "--data-root", "--val-split"),
        )  # fmt: skip
    if config.crop is not None and (
        config.crop[0] > train_set.images.shape[1] or config.crop[1] > train_set.images.shape[2]
    ):
        raise ConfigError(
            f"{config.crop[0]}x{config.crop[1]} is larger than the training images"
            f" ({train_set.images.shape[1]}x{train_set.images.shape[2]}); crop at most that, or leave --crop out",
            field="--crop",
        )
    n_channels = 1 if train_set.channel_obj_ids is None else len(train_set.channel_obj_ids)
    spec = config.network_spec(n_channels)
    torch.manual_seed(config.seed)
    model = UNet(spec).to(device)
    if config.init_weights is not None:
        start_from(model, config.init_weights, train_set.channel_obj_ids)
    trainable = _freeze_all_but(model, config.train_only)
    optimiser = torch.optim.Adam(trainable, lr=config.lr)
    history: list[EpochRecord] = []
    start_epoch = 0
    if resume and checkpoint_path.exists():
        start_epoch, history = _restore(checkpoint_path, config, model, optimiser, device)
        if start_epoch > config.epochs:  # its weights are of a later epoch than asked: nothing would match
            raise ConfigError(
                f"{run_dir} holds {start_epoch} epochs already, more than --epochs {config.epochs}: give --epochs"
                f" {start_epoch} or more to go on, or another --out",
                field="--epochs",
            )
        say(f"resuming {run_dir} after epoch {start_epoch}")
    elif resume:  # a resumable job's first start (scripts rerun the same command): go on, but say so
        say(f"--resume: {run_dir} holds no checkpoint yet; starting a new run")
    only = (
        f", training only {','.join(config.train_only)} ({sum(p.numel() for p in trainable):,})"
        if config.train_only
        else ""
    )
    say(
        f"training {spec.name} ({sum(p.numel() for p in model.parameters()):,} parameters{only}) on {len(train_set)} views"
        f" of {config.dataset} {config.split}" + (f", validating on {len(val_set)}" if val_set else "") + f", {device}"
    )
    aug = AugmentConfig() if config.augment else AugmentConfig.none()
    t_start = time.perf_counter()
    for epoch in range(start_epoch, config.epochs):
        record = _train_epoch(model, optimiser, train_set, config, aug, epoch, device, progress)
        if val_set is not None:
            record.val = evaluate(model, val_set, device, targets)
        history.append(record)
        extra = {"epoch": epoch + 1, "config": config.as_dict(), "history": [asdict(h) for h in history]}
        threshold = record.val.get("curvature_best_threshold")
        if threshold is not None and 0.0 < threshold < 1.0:  # this epoch's calibration (NetWeights.curvature_threshold)
            extra[CURVATURE_THRESHOLD] = float(threshold)
        payload = weights_payload(model, kind, train_set.channel_obj_ids, targets, **extra)
        # RUN_DIR and its files appear with the first finished epoch: a run that stops before it (a diverged loss,
        # Ctrl-C, a crash) leaves nothing in --out that was not there before
        run_dir.mkdir(parents=True, exist_ok=True)
        write_text_atomic(run_dir / CONFIG, json.dumps(config.as_dict(), indent=2) + "\n")
        save_weights(run_dir / WEIGHTS, payload)
        payload["optimiser"] = optimiser.state_dict()
        save_weights(checkpoint_path, payload)
        _write_metrics(run_dir / METRICS, history)
        say(_epoch_line(record, config.epochs))
    return TrainSummary(run_dir, config.epochs, start_epoch, history, time.perf_counter() - t_start)


def _freeze_all_but(model: UNet, train_only: tuple[str, ...]) -> list[torch.nn.Parameter]:
    """Freezes (``requires_grad`` False) every top-level module not named in ``train_only`` (empty: none) and returns
    the parameters that train; :func:`_train_mode` keeps the frozen modules in eval mode.

    Raises:
        ConfigError: a name that is not a top-level module of the network, or one without parameters.
    """
    if not train_only:
        return list(model.parameters())
    children = {name: module for name, module in model.named_children() if any(True for _ in module.parameters())}
    unknown = [name for name in train_only if name not in children]
    if unknown:
        raise ConfigError(
            f"{', '.join(unknown)}: not a module of the {model.spec.name} network; expected some of {', '.join(children)}",
            field="--train-only",
        )
    trainable = []
    for name, module in children.items():
        for p in module.parameters():
            p.requires_grad_(name in train_only)
            if name in train_only:
                trainable.append(p)
    return trainable


def _train_mode(model: UNet, train_only: tuple[str, ...]) -> None:
    """``model`` in training mode, but for the frozen modules (``train_only`` given and not naming them), whose
    batch norms keep their statistics."""
    model.train()
    if train_only:
        for name, module in model.named_children():
            if name not in train_only:
                module.eval()


def _open_samples(
    dataset,
    root,
    split,
    limit,
    targets,
    cache_dir,
    progress,
    channel_obj_ids=None,
    flags=("--data-root", "--split"),
    votes=False,
) -> SampleSet:
    """The samples of one split; an error about the data names this split's own flags (``--val-split`` ...)."""
    try:
        ds = open_dataset(DatasetRequest(dataset=dataset, root=None if root is None else Path(root), split=split))
    except BopCenderError as exc:
        renamed = dict(zip(("--data-root", "--split"), flags, strict=True)).get(exc.field or "")
        if renamed is None or renamed == exc.field:
            raise
        raise type(exc)(exc.message, file=exc.file, field=renamed) from None
    keys = ds.scene_keys[:limit] if limit else ds.scene_keys
    return load_samples(ds, targets, MeshCache(ds.models), cache_dir, channel_obj_ids, keys, progress, votes)


def _restore(path: Path, config: TrainConfig, model: UNet, optimiser, device) -> tuple[int, list[EpochRecord]]:
    weights = load_weights(path)
    saved = weights.extra.get("config")
    if not isinstance(saved, dict) or "optimiser" not in weights.extra:
        raise ConfigError("is not a training checkpoint (no config or optimiser state)", file=path)

    def unusable(field: str, e: Exception) -> ConfigError:  # another version's checkpoint, or an edited one
        return ConfigError(f"cannot resume from this checkpoint ({type(e).__name__}: {e}): use another --out",
                           file=path, field=field)  # fmt: skip

    try:
        crop = saved.get("crop")
        saved_config = TrainConfig(**{**saved, "crop": None if crop is None else tuple(crop)})
    except (TypeError, ValueError, ConfigError) as e:
        raise unusable("config", e) from None
    if not config.same_run_as(saved_config):
        diff = sorted(k for k, v in config.as_dict().items() if k != "epochs" and saved.get(k) != v)
        raise ConfigError(f"was trained with other settings ({', '.join(diff)}): use another --out", file=path)
    epoch = weights.extra.get("epoch")
    if not isinstance(epoch, int) or isinstance(epoch, bool) or epoch < 0:
        raise ConfigError(f"expected the number of epochs trained, got {epoch!r}", file=path, field="epoch")
    records = weights.extra.get("history", [])
    try:
        history = [EpochRecord(**h) for h in records]
    except (TypeError, ValueError) as e:
        raise unusable("history", e) from None
    model.load_state_dict(weights.model.state_dict())
    try:
        optimiser.load_state_dict(weights.extra["optimiser"])
    except (TypeError, ValueError, KeyError, RuntimeError) as e:
        raise unusable("optimiser", e) from None
    for state in optimiser.state.values():  # the optimiser's moments follow the model's device
        for k, v in state.items():
            if isinstance(v, torch.Tensor) and k != "step":
                state[k] = v.to(device)
    return epoch, history


def center_loss(logits: torch.Tensor, target: torch.Tensor, pos_weight: float = 0.0) -> torch.Tensor:
    """Mean BCE-with-logits of center ``logits`` against ``target`` (both ``(B, C, H, W)``), each pixel weighted
    ``1 + pos_weight * target`` (0: plain BCE, the paper's)."""
    weight = None if pos_weight == 0 else 1.0 + pos_weight * target
    return F.binary_cross_entropy_with_logits(logits, target, weight=weight)


def center_focal_loss(
    logits: torch.Tensor, target: torch.Tensor, alpha: float = 2.0, beta: float = 4.0, peak_min: float = 0.9
) -> torch.Tensor:
    """CenterNet's penalty-reduced focal loss (Zhou et al. 2019, "Objects as Points", eq. 1) of center ``logits``
    against the Gaussian-blob ``target`` (both ``(B, C, H, W)``), summed and divided by the number of blobs.

    A blob's peak pixel (a local maximum of ``target`` over its 3x3 neighbourhood, at least ``peak_min``: a
    blob centred anywhere inside a pixel of sigma >= 1.2 px peaks above 0.9 there) is a positive with weight
    ``(1 - p)^alpha``; every other pixel a negative with weight ``(1 - target)^beta p^alpha``, so that the
    pixels next to a centre are barely penalised and confident background not at all.
    """
    peaks = (target >= peak_min) & (target >= F.max_pool2d(target, 3, stride=1, padding=1))
    p = torch.sigmoid(logits)
    positive = (1 - p).pow(alpha) * F.logsigmoid(logits)
    negative = (1 - target).pow(beta) * p.pow(alpha) * F.logsigmoid(-logits)
    total = torch.where(peaks, positive, negative).sum()
    return -total / peaks.sum().clamp(min=1)


#: Pixels whose strongest blob exceeds this are classified by a factored head's class loss (about 1.55 sigma from
#: a centre: the blob's core, where stage 2's peaks and their per-view scores are read).
CLASS_TARGET_MIN = 0.3


def center_class_loss(class_logits: torch.Tensor, target: torch.Tensor, min_target: float = CLASS_TARGET_MIN):
    """Cross-entropy of a factored head's ``class_logits (B, C, H, W)`` over the pixels where the strongest of the
    center ``target (B, C, H, W)`` blobs exceeds ``min_target``, against that blob's channel (the nearer centre
    where two overlap); 0 where no pixel qualifies."""
    strongest, label = target.max(dim=1)
    label = torch.where(strongest > min_target, label, torch.full_like(label, -100))
    if not (label >= 0).any():
        return class_logits.sum() * 0.0
    return F.cross_entropy(class_logits, label, ignore_index=-100)


def _center_loss(config: TrainConfig, logits: torch.Tensor, target: torch.Tensor, factored: bool) -> torch.Tensor:
    """The training run's center loss, weighted by ``config.center_loss_weight``; for a factored head's ``logits
    (B, 1 + C, H, W)`` that of the class-agnostic logit against the channels' max, plus the class loss."""
    extra = 0.0
    if factored:
        extra = config.class_loss_weight * center_class_loss(logits[:, 1:], target)
        logits, target = logits[:, :1], target.amax(dim=1, keepdim=True)
    if config.center_loss == "focal":
        loss = center_focal_loss(logits, target)
    else:
        loss = center_loss(logits, target, config.center_pos_weight)
    return config.center_loss_weight * loss + extra


def _epoch_generator(seed: int, epoch: int, salt: int) -> torch.Generator:
    return torch.Generator().manual_seed(int(np.random.default_rng([seed, epoch, salt]).integers(2**62)))


def _train_epoch(model, optimiser, samples: SampleSet, config, aug, epoch, device, progress) -> EpochRecord:
    _train_mode(model, config.train_only)
    order = torch.randperm(len(samples), generator=_epoch_generator(config.seed, epoch, 0)).numpy()
    batches = [order[i : i + config.batch_size] for i in range(0, len(order), config.batch_size)]
    gen = _epoch_generator(config.seed, epoch, 1)
    camera_gen = _epoch_generator(config.seed, epoch, 2)
    totals = np.zeros(3)
    seen = 0
    t0 = time.perf_counter()
    bar = progress_bar(
        batches, desc=f"epoch {epoch + 1}/{config.epochs}", unit="batch", disable=not progress, leave=False
    )
    for number, idx in enumerate(bar, 1):
        image, center, curvature = samples.batch(idx, device)
        votes = samples.vote_batch(idx, device) if model.spec.center_votes else None
        if config.crop is not None:
            image, center, curvature, votes = random_crop(image, center, curvature, config.crop, gen, votes)
        image, center, curvature, votes = augment_with_votes(image, center, curvature, votes, aug, gen)
        if config.camera_augment:
            image = camera_augment(image, camera_gen)
        with torch.autocast(device_type="cuda", dtype=torch.bfloat16, enabled=device.type == "cuda"):
            center_logits, curvature_logits, vote_logits = model.forward_outputs(image)
        loss_center = _center_loss(config, center_logits.float(), center, model.spec.factored_centers)
        if vote_logits is not None:  # the centre terms (train_center_loss) hold the votes' too
            loss_center = loss_center + config.vote_loss_weight * vote_loss(vote_logits.float(), votes)
        loss_curvature = F.binary_cross_entropy_with_logits(curvature_logits.float(), curvature)
        loss = loss_center + loss_curvature
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        n = len(idx)
        values = np.array([loss.item(), loss_center.item(), loss_curvature.item()])
        if not np.isfinite(values).all():
            raise _diverged(config, epoch, len(batches), number, f"the loss became {values[0]}")
        totals += n * values
        seen += n
        bar.set_postfix(loss=f"{totals[0] / seen:.4f}", img_s=f"{seen / (time.perf_counter() - t0):.1f}")
    bar.close()
    if not all(bool(torch.isfinite(p).all()) for p in model.parameters()):
        raise _diverged(config, epoch, len(batches), len(batches), "the weights became non-finite")
    wall = time.perf_counter() - t0
    mean = totals / max(seen, 1)
    return EpochRecord(epoch + 1, float(mean[0]), float(mean[1]), float(mean[2]), seen / wall, wall)


def _diverged(config: TrainConfig, epoch: int, batches: int, batch: int, what: str) -> ConfigError:
    """The error that stops a diverged run: nothing of this epoch is written, the last checkpoint stands."""
    kept = f"epoch {epoch}'s checkpoint stands" if epoch else "no checkpoint was written"
    return ConfigError(
        f"training diverged: {what} at epoch {epoch + 1}, batch {batch} of {batches}; nothing of this epoch was"
        f" written ({kept}). Train again into another --out with a smaller --lr (this run: {config.lr:g}),"
        " from --init-weights RUN/weights.pt to keep the epochs done",
        field="--lr",
    )


def random_crop(
    image: torch.Tensor,
    center: torch.Tensor,
    curvature: torch.Tensor,
    size: tuple[int, int],
    gen: torch.Generator,
    votes: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """One random ``size`` window per sample, the same for the image and the targets (no crop where the image is
    not larger; ``train`` refuses a crop larger than its images).

    image ``(B, 3, H, W)``, center ``(B, C, H, W)``, curvature ``(B, H, W)``; ``votes`` ``(B, 4, H, W)`` (the vote
    targets: offsets are relative, a crop leaves them as they are) or None, returned as None."""
    B, _, H, W = image.shape
    h, w = min(size[0], H), min(size[1], W)
    top = torch.randint(0, H - h + 1, (B,), generator=gen).tolist()
    left = torch.randint(0, W - w + 1, (B,), generator=gen).tolist()

    def pick(x: torch.Tensor) -> torch.Tensor:
        return torch.stack([x[b, ..., y : y + h, u : u + w] for b, (y, u) in enumerate(zip(top, left, strict=True))])

    return pick(image), pick(center), pick(curvature), None if votes is None else pick(votes)


@torch.no_grad()
def evaluate(model: UNet, samples: SampleSet, device, targets: TargetConfig, batch_size: int = 8) -> dict[str, float]:
    """Validation figures of ``model`` on ``samples``: mean losses and :class:`HeatmapMetrics`' figures (a factored
    network's classes restricted to each view's scene ids, as ``run`` restricts them; the losses are unrestricted)."""
    model.eval()
    metrics = HeatmapMetrics(HeatmapMetricsConfig())
    losses = np.zeros(2)
    factored = model.spec.factored_centers
    for i in range(0, len(samples), batch_size):
        image, center, curvature = samples.batch(range(i, min(i + batch_size, len(samples))), device)
        raw, k_logits, votes = model.forward_outputs(image)
        n = image.shape[0]
        c_logits = factored_center_logits(raw) if factored else raw
        c_prob, _ = model.probabilities_of(
            raw, k_logits, votes, _class_masks(samples, range(i, i + n)) if factored else None
        )
        losses += n * np.array(
            [
                F.binary_cross_entropy_with_logits(c_logits.float(), center).item(),
                F.binary_cross_entropy_with_logits(k_logits.float(), curvature).item(),
            ]
        )
        metrics.update(c_prob, torch.sigmoid(k_logits.float()), center, curvature)
    out = {"center_loss": float(losses[0] / len(samples)), "curvature_loss": float(losses[1] / len(samples))}
    out.update({k: float(v) for k, v in metrics.result().items()})
    return out


def _class_masks(samples: SampleSet, indices) -> torch.Tensor | None:
    """``(B, C)`` bool: per sample, the center channels of its scene's object ids (a factored network's classes are
    restricted to them at validation, as ``run`` restricts them); None where the samples do not know them."""
    if samples.scene_obj_ids is None or samples.channel_obj_ids is None:
        return None
    return torch.stack([known_class_mask(samples.channel_obj_ids, samples.scene_obj_ids[j]) for j in indices])


def _write_metrics(path: Path, history: list[EpochRecord]) -> None:
    rows = [h.row() for h in history]
    columns = list(dict.fromkeys(k for r in rows for k in r))
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    write_text_atomic(path, buffer.getvalue())


def _epoch_line(r: EpochRecord, epochs: int) -> str:
    line = f"epoch {r.epoch}/{epochs}: loss {r.train_loss:.4f}, {r.images_per_s:.1f} images/s, {r.wall_s:.0f} s"
    if r.val:
        line += (
            f"; val center F1 {r.val.get('center_f1', float('nan')):.3f}, curvature AP"
            f" {r.val.get('curvature_ap', float('nan')):.3f}"
        )
    return line
