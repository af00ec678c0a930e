"""Training samples of stage 1: every view of a split with its GT heatmaps, rendered once and cached.

Rendering the targets of a scene costs about as much as a training step on it, so epochs never render:
each scene's targets are written once to ``<cache>/targets/<dataset>-<split>/<scene>-<digest>.npz``
(uint8, ``round(255 * target)``) and read back afterwards. The digest covers everything the targets
depend on (the target config and channels, the views' intrinsics, poses and sizes, the GT poses, the
models' boxes and mesh files), so a changed dataset or config never reads a stale file.

Images and targets of the whole split are held in memory as uint8: 245 kB + 82 kB per 320x256 DIMO
view, plus its center blobs' bounding boxes (:class:`bop_cender.net.patch_maps.PatchMaps`: at most 82 kB per
channel; a T-LESS-layout view's 30 channels, 11.7 MB dense, take tens of kB).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from bop_cender.data.bop_io import atomic_path
from bop_cender.data.canvas import on_one_canvas
from bop_cender.data.types import Dataset, ObjectModel, Scene
from bop_cender.errors import DatasetError
from bop_cender.net.patch_maps import PatchMaps
from bop_cender.net.predictor import scene_rgb
from bop_cender.net.targets import TargetConfig, center_channel_ids, scene_targets_with_votes
from bop_cender.net.votes import VoteTargets, dense_vote_targets
from bop_cender.progress import progress_bar
from bop_cender.render.mesh import RenderMesh

#: Bump when the targets' definition changes, so that old cache files are never read.
TARGETS_CACHE_VERSION = 2  # 2: with the centre votes' id maps and tables


@dataclass
class SampleSet:
    """Views of a split with their GT heatmaps, as uint8 in memory.

    Attributes:
        images: ``(N, H, W, 3)`` uint8 RGB.
        center: ``(N, C, H, W)`` uint8 ``round(255 * center target)``, kept as patches of its non-zero pixels.
        curvature: ``(N, H, W)`` uint8, ``round(255 * curvature target)``.
        keys: ``(scene key, im_id)`` of each sample.
        channel_obj_ids: object id of each center channel, None for one shared channel.
        scene_obj_ids: per sample, the object ids of its scene's GT (what ``run`` knows of an image: a factored
            network's classes are restricted to them at validation as in ``run``); None: unknown.
        vote_ids, vote_tables: the centre votes' targets (:class:`~bop_cender.net.votes.VoteTargets`): ``(N, H, W)``
            uint8 id maps and per sample its ``(K, 3)`` table; None unless loaded with ``votes=True``.
    """

    images: np.ndarray
    center: PatchMaps
    curvature: np.ndarray
    keys: list[tuple[str, int]]
    channel_obj_ids: tuple[int, ...] | None
    scene_obj_ids: list[frozenset[int]] | None = None
    vote_ids: np.ndarray | None = None
    vote_tables: list[np.ndarray] | None = None

    def __len__(self) -> int:
        return len(self.keys)

    def batch(self, indices: Sequence[int] | np.ndarray, device: torch.device | str = "cpu"):
        """Samples ``indices`` as float32 tensors on ``device``: image ``(B, 3, H, W)``, center ``(B, C, H, W)``
        and curvature ``(B, H, W)``, all in [0, 1]."""
        idx = np.asarray(indices, dtype=np.int64)
        image = torch.from_numpy(self.images[idx]).to(device).permute(0, 3, 1, 2).float().div_(255.0)
        center = torch.from_numpy(self.center.dense(idx)).to(device).float().div_(255.0)
        curvature = torch.from_numpy(self.curvature[idx]).to(device).float().div_(255.0)
        return image.contiguous(), center, curvature

    def vote_batch(self, indices: Sequence[int] | np.ndarray, device: torch.device | str = "cpu") -> torch.Tensor:
        """Samples ``indices``' dense vote targets ``(B, 4, H, W)`` (:func:`~bop_cender.net.votes.dense_vote_targets`).

        Raises:
            ValueError: the set was loaded without votes."""
        if self.vote_ids is None or self.vote_tables is None:
            raise ValueError("these samples were loaded without their vote targets (load_samples(votes=True))")
        idx = np.asarray(indices, dtype=np.int64)
        ids = torch.from_numpy(self.vote_ids[idx]).to(device)
        return dense_vote_targets(ids, [self.vote_tables[i] for i in idx])


def load_samples(
    dataset: Dataset,
    config: TargetConfig,
    meshes: Callable[[int], RenderMesh],
    cache_dir: Path | None,
    channel_obj_ids: tuple[int, ...] | None = None,
    scene_keys: Sequence[str] | None = None,
    progress: bool = True,
    votes: bool = False,
) -> SampleSet:
    """Every view of ``dataset``'s scenes (or of ``scene_keys``) with its targets, from the cache where possible;
    with ``votes``, the centre votes' targets too (:mod:`bop_cender.net.votes`).

    Raises:
        DatasetError: a view without a colour image, or views of different sizes.
    """
    keys = list(dataset.scene_keys if scene_keys is None else scene_keys)
    channel_obj_ids = center_channel_ids(dataset.models, config, channel_obj_ids)
    images, centers, curvatures, sample_keys, obj_ids = [], [], [], [], []
    vote_ids: list[np.ndarray] = []
    vote_tables: list[np.ndarray] = []
    size = None
    for key in progress_bar(keys, desc=f"targets {dataset.name} {dataset.split}", unit="scene", disable=not progress):
        scene = on_one_canvas(dataset.loader(key))  # a multi-sensor capture's cameras at the evaluated one's size
        rgb = scene_rgb(scene)
        if size is None:
            size = rgb.shape[1:3]
        elif rgb.shape[1:3] != size:
            raise DatasetError(
                f"scene {key}'s images are {rgb.shape[2]}x{rgb.shape[1]}; the split's first were"
                f" {size[1]}x{size[0]}: one image size per training set",
                file=scene.views[0].source,
            )
        center, curvature, scene_votes = _scene_targets_cached(
            scene, dataset, config, meshes, channel_obj_ids, cache_dir
        )
        images.extend(rgb)
        centers.append(PatchMaps.from_dense(center))  # dense maps of one scene at a time in memory
        for i, view in enumerate(scene.views):
            curvatures.append(curvature[i])
            if votes:
                vote_ids.append(scene_votes.ids[i])
                vote_tables.append(scene_votes.tables[i])
            sample_keys.append((key, view.im_id))
            obj_ids.append(frozenset(g.obj_id for g in scene.gt))
    if not sample_keys:
        raise DatasetError(f"{dataset.name} split {dataset.split} has no views to train on", file=dataset.root)
    return SampleSet(
        np.stack(images),
        PatchMaps.concat(centers),
        np.stack(curvatures),
        sample_keys,
        channel_obj_ids,
        obj_ids,
        np.stack(vote_ids) if votes else None,
        vote_tables if votes else None,
    )


def _scene_targets_cached(
    scene: Scene,
    dataset: Dataset,
    config: TargetConfig,
    meshes: Callable[[int], RenderMesh],
    channel_obj_ids: tuple[int, ...] | None,
    cache_dir: Path | None,
) -> tuple[np.ndarray, np.ndarray, VoteTargets]:
    """``(V, C, H, W)`` and ``(V, H, W)`` uint8 targets of ``scene`` and its :class:`VoteTargets`, rendered or read
    from the cache."""
    path = None
    if cache_dir is not None:
        digest = targets_digest(scene, dataset.models, config, channel_obj_ids)
        folder = Path(cache_dir) / "targets" / f"{dataset.name}-{dataset.split}"
        path = folder / f"{scene.key.replace('/', '_')}-{digest}.npz"
        if path.is_file():
            ids = center_channel_ids(dataset.models, config, channel_obj_ids)
            cached = _read_cached_targets(path, scene, 1 if ids is None else len(ids))
            if cached is not None:
                return cached
    maps, votes = scene_targets_with_votes(scene, dataset.models, meshes, config, channel_obj_ids)
    center = _quantise(maps.center)
    curvature = _quantise(maps.curvature)
    if path is not None:
        table = np.concatenate(
            [np.concatenate([np.full((len(t), 1), v, np.float32), t], axis=1) for v, t in enumerate(votes.tables)]
        ).reshape(-1, 4)
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path, ".npz") as tmp, open(tmp, "wb") as f:
            np.savez_compressed(f, center=center, curvature=curvature, vote_ids=votes.ids, vote_table=table)
    return center, curvature, votes


def _read_cached_targets(path: Path, scene: Scene, channels: int) -> tuple[np.ndarray, np.ndarray, VoteTargets] | None:
    """The cached targets of ``scene`` in ``path``, or None where the file is damaged (truncated, not an archive,
    corrupted bytes) or holds anything but what :func:`_scene_targets_cached` writes for this scene: ``center``
    uint8 ``(V, channels, H, W)``, ``curvature`` and ``vote_ids`` uint8 ``(V, H, W)``, ``vote_table`` float32
    ``(N, 4)`` finite rows ``(view, x, y, area)`` with every view's ids within its rows. None: rendered again and
    replaced, so that a damaged cache never stops a training run."""
    V, H, W = len(scene.views), scene.views[0].height, scene.views[0].width
    try:
        with np.load(path) as data:
            center, curvature = data["center"], data["curvature"]
            vote_ids, table = data["vote_ids"], data["vote_table"]
    except Exception:  # noqa: BLE001 - zip, zlib, pickle and I/O errors alike: the file is rendered again
        return None
    ok = (
        center.dtype == np.uint8
        and center.shape == (V, channels, H, W)
        and all(a.dtype == np.uint8 and a.shape == (V, H, W) for a in (curvature, vote_ids))
        and table.dtype == np.float32
        and table.ndim == 2
        and table.shape[1] == 4
        and bool(np.isfinite(table).all())
    )
    if not ok:
        return None
    views = table[:, 0].astype(np.int64)
    if not (np.array_equal(views, table[:, 0]) and np.all((views >= 0) & (views < V))):
        return None
    tables = tuple(table[views == v, 1:] for v in range(V))
    if any(int(vote_ids[v].max(initial=0)) > len(tables[v]) for v in range(V)):
        return None
    return center, curvature, VoteTargets(vote_ids, tables)


def _quantise(x: torch.Tensor) -> np.ndarray:
    return (x.detach().cpu().clamp(0, 1) * 255.0).round().to(torch.uint8).numpy()


def targets_digest(
    scene: Scene, models: Mapping[int, ObjectModel], config: TargetConfig, channel_obj_ids: tuple[int, ...] | None
) -> str:
    """16 hex digits over everything ``scene``'s targets depend on (see the module docstring)."""
    h = hashlib.sha256()
    h.update(json.dumps({"version": TARGETS_CACHE_VERSION, "config": asdict(config)}, sort_keys=True).encode())
    h.update(repr(channel_obj_ids).encode())
    for v in scene.views:
        h.update(f"{v.im_id} {v.width} {v.height}".encode())
        h.update(np.asarray(v.K, np.float64).tobytes())
        h.update(np.asarray(v.T_cam_world, np.float64).tobytes())
    for g in scene.gt:
        h.update(str(g.obj_id).encode())
        h.update(np.asarray(g.T_world_model, np.float64).tobytes())
        h.update(repr(sorted(g.visib_fract.items())).encode())
    for obj_id in sorted({g.obj_id for g in scene.gt if g.obj_id in models}):
        m = models[obj_id]
        h.update(f"{obj_id} {m.is_target}".encode())
        h.update(np.asarray(m.bbox_min, np.float64).tobytes() + np.asarray(m.bbox_size, np.float64).tobytes())
        try:
            st = Path(m.path).stat()
            h.update(f"{st.st_size} {st.st_mtime_ns}".encode())
        except (OSError, TypeError):
            h.update(b"no-file")
    return h.hexdigest()[:16]
