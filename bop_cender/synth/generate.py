"""Generate a synthetic dataset in the DIMO, T-LESS or BOP-Industrial layout: models, scenes in parallel, targets.

Deterministic per seed (every scene derives its generator from ``(seed, scene)``, so the output
does not depend on the number of workers or on the order of completion), resumable (scene folders
are written atomically and marked done, :mod:`bop_cender.synth.done`; the root's record,
:mod:`bop_cender.synth.record`, refuses a resume with another seed or catalogue), with a progress bar on
stderr. A resume finds out what is done before any set-up (models, meshes, worker processes): finished
folders cost one ``stat`` per file, and the bar counts only the folders still to write.

What differs between layouts is one small protocol (:mod:`bop_cender.synth.layouts`). A worker process keeps its
models and meshes in one explicit :class:`~bop_cender.synth.layouts.LayoutWorker`, set by the pool's initializer.
The jobs run in this process, in a pool of processes (``workers``), or on a Ray cluster (``executor="ray"``,
:mod:`bop_cender.synth.ray_generate`: the actors send each job's files back, written here the same way).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path

import torch

from bop_cender.cluster import check_executor
from bop_cender.progress import progress_bar
from bop_cender.synth.done import scene_done
from bop_cender.synth.layouts import LAYOUTS, LayoutWorker
from bop_cender.synth.record import check_or_write_record, mark_complete
from bop_cender.synth.resume_check import check_done_folder


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


#: This process's worker (set by :func:`_init_worker`: a pool's initializer, or :func:`generate` itself).
_WORKER: LayoutWorker | None = None
#: The process that started this worker (a pool worker stops once it is gone, see :func:`_run_job`).
_PARENT_PID: int | None = None


def _init_worker(layout: str, spec, threads: int, parent_pid: int | None = None) -> None:
    global _WORKER, _PARENT_PID
    _PARENT_PID = parent_pid
    torch.set_num_threads(threads)
    _WORKER = LayoutWorker.build(layout, spec)


def _run_job(root: str, job) -> int:
    """One scene job. A pool worker whose ``synth`` was killed (its parent gone) takes no further job: the queued
    ones would otherwise go on being written behind the user's back, beside a resumed run."""
    assert _WORKER is not None, "_init_worker runs first"
    if _PARENT_PID is not None and os.getppid() != _PARENT_PID:
        os._exit(1)
    return _WORKER.run(root, job)


def _write_jobs(
    layout: str, root: Path, spec, todo: list, workers: int | None, executor: str, address: str | None
) -> Iterator[int]:
    """Run the jobs ``todo`` and yield the folders each wrote, as jobs finish: the one place the executor is chosen
    (this process, a pool of processes, or Ray actors)."""
    if executor == "ray":
        from bop_cender.synth.ray_generate import ray_jobs

        yield from ray_jobs(layout, root, spec, todo, workers, address)
        return
    workers = min(workers or 1, len(todo))
    if workers == 1:
        _init_worker(layout, spec, torch.get_num_threads())
        for job in todo:
            yield _run_job(str(root), job)
        return
    threads = max(1, (os.cpu_count() or 1) // workers)
    # Spawned, not forked: this process has imported torch (and may have run it), and a fork copies
    # MKL's allocator and the OpenMP pool mid-use, which can hang the worker (see eval/render_process.py).
    ctx = get_context("spawn")
    with ProcessPoolExecutor(
        workers, mp_context=ctx, initializer=_init_worker, initargs=(layout, spec, threads, os.getpid())
    ) as pool:
        futures = [pool.submit(_run_job, str(root), job) for job in todo]
        for f in as_completed(futures):
            yield f.result()


def generate(
    layout: str,
    root: str | Path,
    spec,
    workers: int | None = 1,
    progress: bool = True,
    announce: Callable[[str], None] | None = None,
    executor: str = "local",
    address: str | None = None,
) -> GenerationReport:
    """Generate (or complete) a dataset.

    Args:
        layout: ``dimo``, ``tless`` or ``industrial``.
        root: output folder (created; existing done scenes are kept, if its record, written on the first
            run, names the same layout, seed and catalogue seed).
        spec: :class:`~bop_cender.synth.write_dimo.DimoSpec`, :class:`~bop_cender.synth.write_tless.TlessSpec` or
            :class:`~bop_cender.synth.write_industrial.IndustrialSynthSpec`.
        workers: processes (1 or None = in this process), or Ray actors (None: one per CPU of the cluster); never
            more than the jobs left.
        progress: progress bar on stderr.
        announce: called with one line when a resume finds scene folders done.
        executor: ``local`` (this machine) or ``ray`` (a Ray cluster, :mod:`bop_cender.synth.ray_generate`).
        address: the Ray cluster (``auto``, ``HOST:PORT``; None: a Ray instance started here for the command).

    Raises:
        ConfigError: bad executor options (before anything is written), Ray missing or its cluster unreachable.
    """
    if layout not in LAYOUTS:
        raise ValueError(f"unknown layout {layout!r}; expected one of {sorted(LAYOUTS)}")
    check_executor(executor, address, workers)
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
        for n in _write_jobs(layout, root, spec, todo, workers, executor, address):
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
