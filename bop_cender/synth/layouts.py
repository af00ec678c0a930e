"""The dataset layouts ``bop-cender synth`` writes, as one small protocol (:class:`SynthLayout`: models, jobs, scenes,
what is written once at the end), its implementations (:data:`LAYOUTS`), and :class:`LayoutWorker`, what a generating
process (this one, a pool worker, a Ray actor) builds once and writes each of its jobs with.

Kept apart from :mod:`bop_cender.synth.generate` (which runs the jobs) so that every executor of the jobs, the local
ones and the Ray actors of :mod:`bop_cender.synth.ray_generate`, writes scenes with the same code.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from bop_cender.data.industrial_params import SYNTH_INDUSTRIAL
from bop_cender.data.layout import sensor_file
from bop_cender.meshes import MeshCache
from bop_cender.synth import write_dimo, write_industrial, write_tless
from bop_cender.synth.models_info import model_folders_complete, write_model_folders
from bop_cender.synth.parts import Part
from bop_cender.synth.piles import PileGeometryCache
from bop_cender.synth.resume_check import FolderShape


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
class LayoutWorker:
    """What a generating process keeps between its jobs: the layout, its spec, the models, their render meshes
    and the piles' per-mesh drop data."""

    layout: SynthLayout
    spec: Any
    models: dict[int, Part]
    meshes: MeshCache
    piles: PileGeometryCache

    @classmethod
    def build(cls, layout: str, spec: Any) -> LayoutWorker:
        """The worker of layout ``layout`` (a key of :data:`LAYOUTS`) for ``spec``: its catalogue made once."""
        impl = LAYOUTS[layout]
        models = impl.models(spec)
        return cls(impl, spec, models, MeshCache(models), PileGeometryCache())

    def run(self, root: str | Path, job: Any) -> int:
        """Write one job's scene folders under ``root`` (those not done); the number written."""
        return self.layout.write_scene(Path(root), self.spec, job, self.models, self.meshes, self.piles)
