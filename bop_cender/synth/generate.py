"""Generate a synthetic dataset in the DIMO or T-LESS layout: models, scenes in parallel, targets.

Deterministic per seed (every scene derives its generator from ``(seed, scene)``, so the output
does not depend on the number of workers or on the order of completion), resumable (scene folders
are written atomically and complete ones are skipped), with a progress bar on stderr.
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

import torch
from tqdm import tqdm

from bop_cender.synth import write_dimo, write_tless
from bop_cender.synth.bop_files import MeshCache

LAYOUTS = {"dimo": write_dimo, "tless": write_tless}


@dataclass
class GenerationReport:
    """What a generation run did."""

    root: Path
    layout: str
    jobs: int
    written: int
    skipped: int
    targets: int | None = None


_worker_state: dict = {}


def _init_worker(layout: str, spec, threads: int) -> None:
    torch.set_num_threads(threads)
    module = LAYOUTS[layout]
    models = module.dimo_models(spec.seed) if layout == "dimo" else module.tless_models(spec)
    _worker_state.update(layout=layout, spec=spec, models=models, meshes=MeshCache(models))


def _run_job(root: str, job) -> int:
    st = _worker_state
    return LAYOUTS[st["layout"]].write_scene(Path(root), st["spec"], job, st["models"], st["meshes"])


def generate(layout: str, root: str | Path, spec, workers: int = 1, progress: bool = True) -> GenerationReport:
    """Generate (or complete) a dataset.

    Args:
        layout: ``dimo`` or ``tless``.
        root: output folder (created; existing complete scenes are kept).
        spec: :class:`~bop_cender.synth.write_dimo.DimoSpec` or :class:`~bop_cender.synth.write_tless.TlessSpec`.
        workers: processes (1 = in this process).
        progress: progress bar on stderr.
    """
    if layout not in LAYOUTS:
        raise ValueError(f"unknown layout {layout!r}; expected one of {sorted(LAYOUTS)}")
    module = LAYOUTS[layout]
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    module.write_models(root, spec)
    jobs = module.scene_jobs(spec)
    written = 0
    bar = tqdm(total=len(jobs), desc=f"synth {layout}", unit="scene", disable=not progress)
    if workers <= 1:
        _init_worker(layout, spec, torch.get_num_threads())
        for job in jobs:
            written += _run_job(str(root), job)
            bar.update()
    else:
        threads = max(1, (os.cpu_count() or 1) // workers)
        with ProcessPoolExecutor(workers, initializer=_init_worker, initargs=(layout, spec, threads)) as pool:
            futures = [pool.submit(_run_job, str(root), job) for job in jobs]
            for f in as_completed(futures):
                written += f.result()
                bar.update()
    bar.close()
    per_job = (int(spec.write_real) + len(spec.variants)) if layout == "dimo" else 1
    folders = len(jobs) * per_job
    targets = write_tless.write_targets(root) if layout == "tless" and spec.n_scenes > 0 else None
    return GenerationReport(root, layout, len(jobs), written, folders - written, targets)
