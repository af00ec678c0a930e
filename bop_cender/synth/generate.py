"""Generate a synthetic dataset in the DIMO, T-LESS or BOP-Industrial layout: models, scenes in parallel, targets.

Deterministic per seed (every scene derives its generator from ``(seed, scene)``, so the output
does not depend on the number of workers or on the order of completion), resumable (scene folders
are written atomically and marked done, :mod:`bop_cender.synth.done`; the root's record,
:mod:`bop_cender.synth.record`, refuses a resume with another seed or catalogue), with a progress bar on
stderr. A resume finds out what is done before any set-up (models, meshes, worker processes): finished
folders cost one ``stat`` per file, and the bar counts only the folders still to write.

What differs between layouts is one small protocol, :class:`SynthLayout` (models, jobs, scenes, what is
written once at the end); :data:`LAYOUTS` holds its implementations. A worker process keeps its
models and meshes in one explicit :class:`_Worker`, set by the pool's initializer.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import Any, Protocol

import torch

from bop_cender.data.industrial_params import SYNTH_INDUSTRIAL
from bop_cender.data.layout import sensor_file
from bop_cender.meshes import MeshCache
from bop_cender.progress import progress_bar
from bop_cender.synth import write_dimo, write_industrial, write_tless
from bop_cender.synth.done import scene_done
from bop_cender.synth.models_info import model_folders_complete, write_model_folders
from bop_cender.synth.parts import Part
from bop_cender.synth.piles import PileGeometryCache
from bop_cender.synth.record import check_or_write_record, mark_complete
from bop_cender.synth.resume_check import FolderShape, check_done_folder


class SynthLayout(Protocol):
    """How one dataset layout is generated; ``spec`` is the layout's spec (DimoSpec, TlessSpec)."""

    name: str

    def models(self, spec: Any) -> dict[int, Part]:
        """The layout's fixed object catalogue (parts and supports), by obj_id."""

    def write_models(self, root: Path, spec: Any) -> None:
        """Write ``models*/`` (and whatever else is written once before the scenes)."""

    def scene_jobs(self, spec: Any) -> list:
        """The independent units of work."""

    def models_written(self, root: Path) -> bool:
        """Whether what :meth:`write_models` writes is all there (then the catalogue need not be made)."""

    def write_scene(
        self, root: Path, spec: Any, job: Any, models: dict[int, Part], meshes: MeshCache, piles: PileGeometryCache
    ) -> int:
        """Write one job's scene folders (skipping done ones); the number written."""

    def job_folders(self, root: Path, spec: Any, job: Any) -> list[Path]:
        """The scene folders one job writes."""

    def folder_shape(self, spec: Any, job: Any, folder: Path) -> FolderShape:
        """What ``spec`` fixes about ``folder`` (one of the job's), checked against it when it is done."""

    def finish(self, root: Path, spec: Any) -> int | None:
        """Write what needs every scene (T-LESS: the BOP'19 targets); the number of targets, None if none."""


class DimoLayout:
    """DIMO: each job is a scene number, written as its real folder and its sim variants."""

    name = "dimo"

    def models(self, spec: write_dimo.DimoSpec) -> dict[int, Part]:
        return write_dimo.dimo_models(spec.catalogue_seed)

    def write_models(self, root: Path, spec: write_dimo.DimoSpec) -> None:
        write_dimo.write_models(root, spec)

    def models_written(self, root: Path) -> bool:
        return model_folders_complete(root, "dimo") and (root / "models" / "construction").is_dir()

    def scene_jobs(self, spec: write_dimo.DimoSpec) -> list:
        return write_dimo.scene_jobs(spec)

    def write_scene(self, root, spec, job, models, meshes, piles) -> int:
        return write_dimo.write_scene(root, spec, job, models, meshes, piles)

    def job_folders(self, root: Path, spec: write_dimo.DimoSpec, job: int) -> list[Path]:
        return write_dimo.job_folders(root, spec, job)

    def folder_shape(self, spec: write_dimo.DimoSpec, job: int, folder: Path) -> FolderShape:
        carrier, composition = write_dimo.scene_carrier_and_composition(spec, job)
        info = {"carrier": (carrier, "--carriers"), "parts": (composition, "--compositions")}
        return FolderShape(spec.n_viewpoints, "--views", info)

    def finish(self, root: Path, spec: write_dimo.DimoSpec) -> int | None:
        return None  # DIMO has no targets file


class TlessLayout:
    """T-LESS (BOP): each job is one test or train_pbr scene folder; the BOP'19 targets are written last."""

    name = "tless"

    def models(self, spec: write_tless.TlessSpec) -> dict[int, Part]:
        return write_tless.tless_models(spec.catalogue_seed)

    def write_models(self, root: Path, spec: write_tless.TlessSpec) -> None:
        write_tless.write_models(root, spec)

    def models_written(self, root: Path) -> bool:
        return model_folders_complete(root, "tless") and (root / write_tless.CAMERA_FILE).is_file()

    def scene_jobs(self, spec: write_tless.TlessSpec) -> list:
        return write_tless.scene_jobs(spec)

    def write_scene(self, root, spec, job, models, meshes, piles) -> int:
        return write_tless.write_scene(root, spec, job, models, meshes, piles)

    def job_folders(self, root: Path, spec: write_tless.TlessSpec, job: tuple[str, int]) -> list[Path]:
        return write_tless.job_folders(root, job)

    def folder_shape(self, spec: write_tless.TlessSpec, job: tuple[str, int], folder: Path) -> FolderShape:
        if job[0] == "test":
            return FolderShape(spec.n_views, "--views")
        return FolderShape(spec.pbr_images, "--pbr-images")

    def finish(self, root: Path, spec: write_tless.TlessSpec) -> int | None:
        return write_tless.write_targets(root) if spec.n_scenes > 0 else None


class IndustrialLayout:
    """BOP-Industrial multi-sensor bins (:mod:`bop_cender.synth.write_industrial`): each job is one test or train
    scene folder; the targets of the evaluated sensor are written last."""

    name = "industrial"

    def models(self, spec: write_industrial.IndustrialSynthSpec) -> dict[int, Part]:
        return write_industrial.industrial_models(spec.catalogue_seed)

    def write_models(self, root: Path, spec: write_industrial.IndustrialSynthSpec) -> None:
        models = write_industrial.industrial_models(spec.catalogue_seed)
        write_model_folders(root, {i: p for i, p in models.items() if i != write_industrial.BIN_ID}, "industrial")

    def models_written(self, root: Path) -> bool:
        return model_folders_complete(root, "industrial")

    def scene_jobs(self, spec: write_industrial.IndustrialSynthSpec) -> list:
        return write_industrial.scene_jobs(spec)

    def write_scene(self, root, spec, job, models, meshes, piles) -> int:
        return write_industrial.write_scene(root, spec, job, models, meshes, piles)

    def job_folders(self, root: Path, spec: write_industrial.IndustrialSynthSpec, job: tuple[str, int]) -> list[Path]:
        return write_industrial.job_folders(root, job)

    def folder_shape(
        self, spec: write_industrial.IndustrialSynthSpec, job: tuple[str, int], folder: Path
    ) -> FolderShape:
        camera = sensor_file("scene_camera", SYNTH_INDUSTRIAL.eval_sensor)
        return FolderShape(spec.n_images, "--views", camera_file=camera)

    def finish(self, root: Path, spec: write_industrial.IndustrialSynthSpec) -> int | None:
        return write_industrial.write_targets(root) if spec.n_scenes > 0 else None


LAYOUTS: dict[str, SynthLayout] = {"dimo": DimoLayout(), "tless": TlessLayout(), "industrial": IndustrialLayout()}


@dataclass
class GenerationReport:
    """What a generation run did."""

    root: Path
    layout: str
    jobs: int
    written: int
    skipped: int
    targets: int | None = None
    others: int = 0
    """Scene folders beside this run's that it did not ask for (an earlier run's, of more scenes): kept."""


@dataclass
class _Worker:
    """What a generating process keeps between its jobs: the layout, its spec, the models, their render meshes
    and the piles' per-mesh drop data."""

    layout: SynthLayout
    spec: Any
    models: dict[int, Part]
    meshes: MeshCache
    piles: PileGeometryCache

    def run(self, root: str, job) -> int:
        return self.layout.write_scene(Path(root), self.spec, job, self.models, self.meshes, self.piles)


#: This process's worker (set by :func:`_init_worker`: a pool's initializer, or :func:`generate` itself).
_WORKER: _Worker | None = None
#: The process that started this worker (a pool worker stops once it is gone, see :func:`_run_job`).
_PARENT_PID: int | None = None


def _init_worker(layout: str, spec, threads: int, parent_pid: int | None = None) -> None:
    global _WORKER, _PARENT_PID
    _PARENT_PID = parent_pid
    torch.set_num_threads(threads)
    impl = LAYOUTS[layout]
    models = impl.models(spec)
    _WORKER = _Worker(impl, spec, models, MeshCache(models), PileGeometryCache())


def _run_job(root: str, job) -> int:
    """One scene job. A pool worker whose ``synth`` was killed (its parent gone) takes no further job: the queued
    ones would otherwise go on being written behind the user's back, beside a resumed run."""
    assert _WORKER is not None, "_init_worker runs first"
    if _PARENT_PID is not None and os.getppid() != _PARENT_PID:
        os._exit(1)
    return _WORKER.run(root, job)


def generate(
    layout: str,
    root: str | Path,
    spec,
    workers: int = 1,
    progress: bool = True,
    announce: Callable[[str], None] | None = None,
) -> GenerationReport:
    """Generate (or complete) a dataset.

    Args:
        layout: ``dimo``, ``tless`` or ``industrial``.
        root: output folder (created; existing done scenes are kept, if its record, written on the first
            run, names the same layout, seed and catalogue seed).
        spec: :class:`~bop_cender.synth.write_dimo.DimoSpec`, :class:`~bop_cender.synth.write_tless.TlessSpec` or
            :class:`~bop_cender.synth.write_industrial.IndustrialSynthSpec`.
        workers: processes (1 = in this process; never more than the jobs left).
        progress: progress bar on stderr.
        announce: called with one line when a resume finds scene folders done.
    """
    if layout not in LAYOUTS:
        raise ValueError(f"unknown layout {layout!r}; expected one of {sorted(LAYOUTS)}")
    impl = LAYOUTS[layout]
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    check_or_write_record(root, layout, spec)  # before anything is written: a mismatched resume changes nothing
    jobs = impl.scene_jobs(spec)
    pending, folders = {}, 0
    mine: set[Path] = set()
    for i, job in enumerate(jobs):
        job_folders = impl.job_folders(root, spec, job)
        mine.update(job_folders)
        done = [p for p in job_folders if scene_done(p)]
        for folder in done:  # before anything is written, as the record's check
            check_done_folder(folder, impl.folder_shape(spec, job, folder))
        pending[i] = len(job_folders) - len(done)
        folders += len(job_folders)
    todo = [jobs[i] for i, n in pending.items() if n]
    # the last check passed: until the last file is written, a killed run leaves a dataset that says so (a run refused
    # above leaves the record as it was). One flag for the folder: a second writer finishing first sets it early.
    mark_complete(root, False)
    to_write = sum(pending.values())
    if announce is not None and to_write < folders:
        announce(f"resuming: {folders - to_write} of {folders} scene folders done, {to_write} to go")
    if not impl.models_written(root):
        impl.write_models(root, spec)
    written = 0
    if todo:
        bar = progress_bar(total=to_write, desc=f"synth {layout}", unit="scene", disable=not progress)
        if workers <= 1 or len(todo) == 1:
            _init_worker(layout, spec, torch.get_num_threads())
            for job in todo:
                n = _run_job(str(root), job)
                written += n
                bar.update(n)
        else:
            workers = min(workers, len(todo))
            threads = max(1, (os.cpu_count() or 1) // workers)
            # Spawned, not forked: this process has imported torch (and may have run it), and a fork copies
            # MKL's allocator and the OpenMP pool mid-use, which can hang the worker (see eval/render_process.py).
            ctx = get_context("spawn")
            with ProcessPoolExecutor(
                workers, mp_context=ctx, initializer=_init_worker, initargs=(layout, spec, threads, os.getpid())
            ) as pool:
                futures = [pool.submit(_run_job, str(root), job) for job in todo]
                for f in as_completed(futures):
                    n = f.result()
                    written += n
                    bar.update(n)
        bar.close()
    targets = impl.finish(root, spec)
    mark_complete(root, True)
    splits = {folder.parent for folder in mine}
    others = sum(
        1 for split in splits for f in split.iterdir() if f.is_dir() and not f.name.startswith(".") and f not in mine
    )
    return GenerationReport(root, layout, len(jobs), written, folders - written, targets, others)
