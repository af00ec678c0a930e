"""Network weights files: what a trained stage 1 is, written so that it is rebuilt exactly and checked on load.

A weights file is a ``torch.save`` dict of plain values (read with ``weights_only=True``: no code runs on
load): the format tag, the :class:`~bop_cender.net.unet.UNetSpec`, the dataset it was trained for, the
center channels' object ids, the target config (so that oracle and network agree on what a heatmap
means) and the state dict. A training checkpoint is the same dict plus the optimiser and the epoch.
Beside shipped weights lies a JSON card (data, seed, command, epochs, wall time, machine, figures).
"""

from __future__ import annotations

import hashlib
import io
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import torch

from bop_cender.data.bop_io import atomic_path
from bop_cender.data.types import ObjectModel
from bop_cender.errors import ConfigError
from bop_cender.net.targets import TargetConfig
from bop_cender.net.unet import UNet, UNetSpec

FORMAT = "bop-cender-unet"
FORMAT_VERSION = 1
#: Key of the calibrated curvature binarisation threshold in a weights file (optional; see :class:`NetWeights`).
CURVATURE_THRESHOLD = "curvature_threshold"
#: Key of the thresholds calibrated on the views of one split (camera / domain), by split name (optional).
CURVATURE_THRESHOLD_BY_SPLIT = "curvature_threshold_by_split"
#: Dataset kinds a weights file is trained for: one shared center channel (DIMO) or one per object id (T-LESS, BOP).
KINDS = ("dimo", "tless")
#: Shipped weights, by dataset: files in ``bop_cender/net/weights/`` (with a ``.json`` card beside each).
SHIPPED = {"dimo": "dimo.pt", "tless": "tless.pt"}


@dataclass(frozen=True)
class NetWeights:
    """A loaded weights file.

    Attributes:
        model: the network, in eval mode, on the CPU.
        dataset: ``dimo`` or ``tless`` (what it was trained for: one shared or per-object center channels).
        channel_obj_ids: object id of each center channel, None for one shared channel.
        targets: the target config it was trained on.
        path: where it was read from.
        curvature_threshold: the binarisation threshold calibrated for its curvature heatmaps (the best-F1
            threshold on its validation views, :meth:`~bop_cender.net.metrics.HeatmapMetrics.curvature_best_threshold`,
            written by ``train`` and ``scripts/calibrate_curvature.py``), in (0, 1); None in files without one.
        extra: everything else in the file (epoch, optimiser state of a checkpoint, ...).
        curvature_threshold_by_split: thresholds calibrated on the validation views of one split, by split name
            (``scripts/calibrate_curvature.py --for-split``): a network's best binarisation moves with the camera
            (the shipped DIMO network: 0.616 on `sim` views, 0.555 on `real` ones; end to end on `real` 0.693 ->
            0.742 AR_MSSD<5%, ``results/accuracy/README.md``). :meth:`curvature_threshold_for` picks.
        sha256: hex digest of the file's bytes as they were read: what a run's shards are fingerprinted with, so that
            a run reads its weights file once (None for weights built in memory).
    """

    model: UNet
    dataset: str
    channel_obj_ids: tuple[int, ...] | None
    targets: TargetConfig
    path: Path
    extra: dict[str, Any]
    curvature_threshold: float | None = None
    curvature_threshold_by_split: Mapping[str, float] = field(default_factory=dict)
    sha256: str | None = None

    def curvature_threshold_for(self, split: str | None) -> tuple[float | None, str | None]:
        """The calibrated threshold for views of ``split`` and the split it was calibrated for: that split's own
        where the weights carry one, else the general one (``curvature_threshold``, split None)."""
        if split is not None and split in self.curvature_threshold_by_split:
            return self.curvature_threshold_by_split[split], split
        return self.curvature_threshold, None


def weights_payload(
    model: UNet, dataset: str, channel_obj_ids: tuple[int, ...] | None, targets: TargetConfig, **extra: Any
) -> dict[str, Any]:
    """The dict written by :func:`save_weights` (a checkpoint adds its optimiser and epoch in ``extra``)."""
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "spec": model.spec.as_dict(),
        "dataset": dataset,
        "channel_obj_ids": None if channel_obj_ids is None else [int(i) for i in channel_obj_ids],
        "targets": asdict(targets),
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        **extra,
    }


def save_weights(path: str | Path, payload: dict[str, Any]) -> None:
    """Write ``payload`` atomically (a crash mid-write leaves the previous file)."""
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    with atomic_path(path) as tmp:
        Path(tmp).write_bytes(buffer.getvalue())


def weights_kind(dataset: str) -> str:
    """The kind of weights a dataset layout takes: ``dimo`` (one shared centre channel) for DIMO, ``tless`` (one
    channel per object id) for T-LESS and every other BOP layout."""
    return "dimo" if dataset == "dimo" else "tless"


def shipped_weights_path(dataset: str) -> Path:
    """The shipped weights for ``dataset`` (any layout name: those of its :func:`weights_kind`).

    Raises:
        ConfigError: none are shipped for it.
    """
    name = SHIPPED.get(weights_kind(dataset))
    path = None if name is None else Path(str(resources.files("bop_cender.net") / "weights" / name))
    if path is None or not path.is_file():
        raise ConfigError(
            f"no shipped network weights for dataset {dataset!r} (shipped: {', '.join(_shipped_names()) or 'none'});"
            " train some with `bop-cender train` and pass --weights",
            field="--weights",
        )
    return path


def _shipped_names() -> list[str]:
    folder = Path(str(resources.files("bop_cender.net") / "weights"))
    return sorted(d for d, n in SHIPPED.items() if (folder / n).is_file())


def check_covers_targets(weights: NetWeights, models: Mapping[int, ObjectModel]) -> None:
    """Refuse weights with one center channel per object (T-LESS kind) that have none for a target object of
    ``models``: that object could never be found, and figures of the network on the dataset would mean nothing.

    Raises:
        ConfigError: naming the weights file and the objects without a channel.
    """
    if weights.channel_obj_ids is None:
        return
    missing = sorted(i for i, m in models.items() if m.is_target and i not in weights.channel_obj_ids)
    if missing:
        raise ConfigError(
            f"the weights have no center channel for object(s) {missing} of this dataset", file=weights.path
        )


def load_weights(path: str | Path, dataset: str | None = None, field: str = "--weights") -> NetWeights:
    """Read and check a weights file (or a training checkpoint).

    Args:
        path: the file.
        dataset: when given, the file must have been trained for this dataset kind (``dimo`` or ``tless``;
            other BOP datasets use ``tless``-kind weights: one center channel per object).
        field: the option that gave the file, named in the errors that concern it (``train`` names
            ``--init-weights``).

    Raises:
        ConfigError: missing, truncated or not a weights file, another architecture than its spec says,
            or trained for another dataset kind; one line naming the file.
    """
    path = Path(path)
    if path.is_dir():
        raise ConfigError("is a directory, not a weights file", file=path, field=field)
    if not path.is_file():
        raise ConfigError("weights file not found", file=path, field=field)
    try:
        data = path.read_bytes()  # once: the digest and the payload come from the same bytes
        payload = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - a truncated or foreign file: torch raises many types
        # torch's own text (a paragraph on weights_only, "[Errno 22]") helps nobody: say what the file is
        raise ConfigError(
            f"not a readable weights file: {_load_failure(exc, path)} ({type(exc).__name__})", file=path
        ) from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise ConfigError(f"not a bop-cender network weights file (no format {FORMAT!r})", file=path)
    if payload.get("format_version") != FORMAT_VERSION:
        raise ConfigError(
            f"weights format version {payload.get('format_version')!r}; this bop-cender reads {FORMAT_VERSION}",
            file=path,
        )
    try:
        spec = UNetSpec.from_dict(payload["spec"])
        kind = str(payload["dataset"])
        channel_obj_ids = _channel_ids(payload["channel_obj_ids"], path)
        targets = TargetConfig(**payload["targets"])
        state = payload["state_dict"]
    except ConfigError as exc:  # a target setting out of range, named by its field
        raise ConfigError(f"malformed weights file ({exc.message})", file=path) from None
    except KeyError as exc:
        raise ConfigError(f"malformed weights file (missing key {exc.args[0]!r})", file=path) from None
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"malformed weights file ({type(exc).__name__}: {_first_line(exc)})", file=path) from None
    _check_channels(path, spec, kind, channel_obj_ids)
    if dataset is not None:
        wanted = weights_kind(dataset)
        if kind != wanted:
            raise ConfigError(
                f"these weights were trained for {kind!r} data; dataset {dataset!r} needs {wanted!r} weights",
                file=path,
                field=field,
            )
    model = UNet(spec)
    try:
        model.load_state_dict(state, strict=True)
    except (RuntimeError, TypeError) as exc:
        raise ConfigError(f"the weights do not fit their network spec: {_first_line(exc, 2)}", file=path) from None
    model.eval()
    _check_finite(path, state)
    threshold = payload.get(CURVATURE_THRESHOLD)
    if threshold is not None and not (isinstance(threshold, float | int) and 0.0 < float(threshold) < 1.0):
        raise ConfigError(f"malformed weights file ({CURVATURE_THRESHOLD}: expected a number in (0, 1), got {threshold!r})",
                          file=path)  # fmt: skip
    by_split = payload.get(CURVATURE_THRESHOLD_BY_SPLIT) or {}
    if not isinstance(by_split, dict) or not all(
        isinstance(k, str) and k and isinstance(v, float | int) and 0.0 < float(v) < 1.0 for k, v in by_split.items()
    ):
        raise ConfigError(f"malformed weights file ({CURVATURE_THRESHOLD_BY_SPLIT}: expected split names with numbers"
                          f" in (0, 1), got {by_split!r})", file=path)  # fmt: skip
    reserved = (
        "spec", "dataset", "channel_obj_ids", "targets", "state_dict", CURVATURE_THRESHOLD, CURVATURE_THRESHOLD_BY_SPLIT
    )  # fmt: skip
    extra = {k: v for k, v in payload.items() if k not in reserved}
    return NetWeights(
        model, kind, channel_obj_ids, targets, path, extra, None if threshold is None else float(threshold),
        {str(k): float(v) for k, v in by_split.items()}, hashlib.sha256(data).hexdigest(),
    )  # fmt: skip


def _channel_ids(ids: Any, path: Path) -> tuple[int, ...] | None:
    """``channel_obj_ids`` as ints (None for one shared channel); anything else names the field."""
    if ids is None:
        return None
    if isinstance(ids, list | tuple) and all(isinstance(i, int) and not isinstance(i, bool) for i in ids):
        return tuple(ids)
    raise ConfigError(
        f"malformed weights file (channel_obj_ids: expected a list of object ids, got {ids!r})", file=path
    )


def _check_channels(path: Path, spec: UNetSpec, kind: str, channel_obj_ids: tuple[int, ...] | None) -> None:
    """The dataset kind and the center channels' object ids agree with the network's center channels (one shared
    channel for ``dimo``; one distinct positive object id per channel for ``tless``).

    Raises:
        ConfigError: they do not (``malformed weights file``, naming the field).
    """
    if kind not in KINDS:
        raise ConfigError(f"malformed weights file (dataset: expected one of {', '.join(KINDS)}, got {kind!r})",
                          file=path)  # fmt: skip
    if kind == "dimo":
        problem = None if channel_obj_ids is None and spec.center_channels == 1 else (
            f"dimo weights have one shared center channel and no channel_obj_ids; got {spec.center_channels}"
            f" channel(s) and {channel_obj_ids!r}"
        )  # fmt: skip
    elif channel_obj_ids is None or len(channel_obj_ids) != spec.center_channels:
        count = "none" if channel_obj_ids is None else len(channel_obj_ids)
        problem = f"expected one object id per center channel ({spec.center_channels}), got {count}"
    elif len(set(channel_obj_ids)) != len(channel_obj_ids) or min(channel_obj_ids) < 1:
        problem = f"expected distinct positive object ids, got {list(channel_obj_ids)}"
    else:
        problem = None
    if problem is not None:
        raise ConfigError(f"malformed weights file (channel_obj_ids: {problem})", file=path)


def _check_finite(path: Path, state: Mapping[str, torch.Tensor]) -> None:
    """Every floating-point tensor of the state dict is finite (a diverged training run writes NaN weights, whose
    heatmaps are NaN: stage 2 would find no centre in any scene and the run would end with an empty CSV).

    Raises:
        ConfigError: a tensor holds NaN or infinite values (``malformed weights file``, naming the first one).
    """
    bad = [k for k, v in state.items() if torch.is_floating_point(v) and not bool(torch.isfinite(v).all())]
    if bad:
        more = f" and {len(bad) - 1} more" if len(bad) > 1 else ""
        raise ConfigError(
            f"malformed weights file (state_dict: non-finite values (NaN or inf) in {bad[0]}{more}:"
            " was it written by a diverged training run?)",
            file=path,
        )


def _load_failure(exc: BaseException, path: Path) -> str:
    """What a failed ``torch.load(weights_only=True)`` most likely means, in a few words."""
    if isinstance(exc, PermissionError):
        return "permission denied"
    try:
        with open(path, "rb") as f:
            head = f.read(4)
    except OSError:
        head = b""
    if head and not head.startswith((b"PK\x03\x04", b"\x80")):  # neither torch.save's zip nor a pickle
        return "not a torch file (neither torch.save's zip archive nor a pickle)"
    if type(exc).__name__ == "UnpicklingError" and "weights_only" in str(exc).lower().replace(" ", "_"):
        return "it holds objects other than tensors and plain values (not written by bop-cender)"
    return "truncated, or not written by torch.save"


def _first_line(exc: BaseException, lines: int = 1, limit: int = 200) -> str:
    """The start of an exception's message on one line (torch's messages run over many)."""
    text = " ".join(line.strip() for line in str(exc).strip().splitlines()[:lines] if line.strip())
    return text if len(text) <= limit else text[: limit - 3] + "..."
