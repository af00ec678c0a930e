"""Stage 3's settings: :class:`PoseConfig`, a frozen tree of sections, each field checked where it enters.

The paper gives 2,000 candidates and bounded Nelder-Mead; every other value is ours and was measured. Each field
below says its unit, its default and where its figures are: ``results/accuracy/README.md``, section "Stage-3
settings: how each default was measured" (the session named there holds the full table). ``--set
poses.SECTION.FIELD=VALUE`` sets a field at any depth (:meth:`bop_cender.method.CenDerNetConfig.with_settings`);
the names before the sections and the options removed for lack of a gain are in
:mod:`bop_cender.pose.config_names`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

from bop_cender.errors import ConfigError
from bop_cender.render.backend import BACKEND_NAMES
from bop_cender.settings_checks import COUNT, COUNT_OR_ZERO, NON_NEGATIVE, POSITIVE, Bound, check_settings

#: What stage 3 searches and refines on: the edge-point proxy (ours) or the paper's render cost.
SEARCH_COSTS = ("edges", "render")


@dataclass(frozen=True)
class NelderMead:
    """One bounded Nelder-Mead run over a pose's rotation-vector perturbation and its centre's position.

    Attributes:
        initial_rotation_rad: initial simplex step of each rotation-vector component (rad; 0.15).
        initial_translation_mm: initial simplex step of each centre coordinate (mm; 4).
        xatol: stop when every vertex is this close to the best (scaled units, ~mm at the surface; 0.05).
        fatol: ... and every cost this close to the best (cost units, pixels; 0.001).
        maxfev: cost evaluations per run, its initial simplex's 7 included (count; 150; 2026-12-03 third session).
    """

    initial_rotation_rad: float = 0.15
    initial_translation_mm: float = 4.0
    xatol: float = 0.05
    fatol: float = 1e-3
    maxfev: int = 150


#: Any Nelder-Mead run; an owner may ask more of its own (:data:`_REFINE_NELDER_MEAD`).
_NELDER_MEAD = {
    "initial_rotation_rad": POSITIVE,
    "initial_translation_mm": POSITIVE,
    "xatol": NON_NEGATIVE,
    "fatol": NON_NEGATIVE,
    "maxfev": COUNT_OR_ZERO,
}
_REFINE_NELDER_MEAD = {**_NELDER_MEAD, "xatol": POSITIVE, "fatol": POSITIVE, "maxfev": COUNT}


@dataclass(frozen=True)
class CandidateSettings:
    """The random candidates of each object and the starts taken from them.

    Attributes:
        n: random poses per object (count; 2000, the paper's; 2026-12-06 eighteenth session).
        translation_sigma_mm: spread of their centre around the 3D centre (mm; 5; 2026-12-06 sixteenth session).
        top_k: starts refined by Nelder-Mead (count; 3; 2026-12-06 seventeenth, 2026-12-07 twenty-third sessions).
        downscale: the render search costs its candidates at 1/this resolution (factor; 2, the paper's 1; 2026-12-02).
        segments: size of the sparse edge model that ranks the candidates (segments; 600; 2026-12-02).
        rerank: best candidates re-ranked by the full edge model (count; 100; 2026-12-03 third session).
        start_separation_rad: least rotation between two starts of the edge search (rad; 0.35; 2026-12-03 third).
        symmetric_separation: measure that rotation modulo the object's symmetries (``models_info``), so that the
            starts of a symmetric part are distinct poses, not copies of one (bool; false, true for bins: oracle
            bop25_mAP +0.02-0.03 on three sets, ``results/accuracy/industrial/README.md``; 2026-12-08).
    """

    n: int = 2000
    translation_sigma_mm: float = 5.0
    top_k: int = 3
    downscale: int = 2
    segments: int = 600
    rerank: int = 100
    start_separation_rad: float = 0.35
    symmetric_separation: bool = False


_CANDIDATES = {
    "n": COUNT,
    "translation_sigma_mm": NON_NEGATIVE,
    "top_k": COUNT,
    "downscale": COUNT,
    "segments": COUNT,
    "rerank": COUNT_OR_ZERO,
    "start_separation_rad": NON_NEGATIVE,
}


@dataclass(frozen=True)
class RefineSettings:
    """The bounded Nelder-Mead refinement of the starts.

    Attributes:
        rotation_bound_rad: bound on each rotation-vector component of the perturbation (rad; 0.6).
        translation_bound_mm: the centre stays in this box around the 3D centre (mm; 20; 2026-12-03 second session).
        nelder_mead: its runs (:class:`NelderMead`, the defaults; ``maxfev`` 150, 2026-12-03 third session).
    """

    rotation_bound_rad: float = 0.6
    translation_bound_mm: float = 20.0
    nelder_mead: NelderMead = field(default_factory=NelderMead)


_REFINE = {"rotation_bound_rad": POSITIVE, "translation_bound_mm": POSITIVE}


@dataclass(frozen=True)
class ScreenSettings:
    """The edge search's screen: more starts refined briefly, the best ``candidates.top_k`` of them go on.

    Attributes:
        starts: diverse candidates refined briefly, <= ``top_k``: no screen (count; 8, T-LESS / BOP 0; 2026-12-03).
        nelder_mead: their short runs (:class:`NelderMead`; ``maxfev`` 30; 2026-12-03 third session).
    """

    starts: int = 8
    nelder_mead: NelderMead = field(default_factory=lambda: NelderMead(maxfev=30))


@dataclass(frozen=True)
class SweepSettings:
    """The sweeps over the objects (the first the paper's sequential placement).

    Attributes:
        passes: sweeps, each further one judged by the scene (count; 3, the paper's 1; 2026-12-02 third, 2026-12-03).
    """

    passes: int = 3


@dataclass(frozen=True)
class ScenePolishSettings:
    """The scene polish after the sweeps (:mod:`bop_cender.pose.scene_polish`).

    Attributes:
        passes: passes over the placed objects, until one keeps nothing (count; 2; 2026-12-06 seventeenth session).
        margin_px: its windows around an object's bounding sphere (pixels; 12).
        nelder_mead: its runs (:class:`NelderMead`; simplex /4, xatol 0.2, fatol 0.005, maxfev 100, 0 off; 2026-12-03).
    """

    passes: int = 2
    margin_px: int = 12
    nelder_mead: NelderMead = field(
        default_factory=lambda: NelderMead(
            initial_rotation_rad=0.15 / 4, initial_translation_mm=1.0, xatol=0.2, fatol=0.005, maxfev=100
        )
    )


_SCENE_POLISH = {"passes": COUNT, "margin_px": COUNT_OR_ZERO}


@dataclass(frozen=True)
class NetworkSettings:
    """Where the 3D centres or the curvature come from a network: these replace the oracle's settings (None: the
    same as for the oracle, except ``t_b``).

    Attributes:
        t_b: a network's curvature threshold in [0, 1) (None: the weights' calibration, else t_b; 2026-12-03 fifth).
        translation_sigma_mm: ``candidates.translation_sigma_mm`` for a network's centres (mm; 10; 2026-12-06).
        translation_bound_mm: ``refine.translation_bound_mm`` for a network's centres (mm; 30; 2026-12-06).
        scene_polish_passes: ``scene_polish.passes`` for a network's centres (count; 1; 2026-12-06 seventeenth).
    """

    t_b: float | None = None
    translation_sigma_mm: float | None = 10.0
    translation_bound_mm: float | None = 30.0
    scene_polish_passes: int | None = 1


_UNIT_INTERVAL = Bound(0.0, 1.0, high_open=True)
_NETWORK = {
    "t_b": replace(_UNIT_INTERVAL, optional=True),
    "translation_sigma_mm": replace(NON_NEGATIVE, optional=True),
    "translation_bound_mm": replace(POSITIVE, optional=True),
    "scene_polish_passes": replace(COUNT, optional=True),
}


@dataclass(frozen=True)
class PoseConfig:
    """Stage-3 settings (figures: ``results/accuracy/README.md``, "Stage-3 settings: how each default was measured").

    Attributes:
        t_b: curvature binarisation threshold in [0, 1) (fraction; 0.75: raw 3 at the targets' scale 4; 2026-12-01).
        occlusion: the objects already placed hide the next ones (flag; true, the paper's; 2026-12-06 eighteenth).
        search_cost: ``edges`` (the edge-point proxy; ours) or ``render`` (the paper's render cost; 2026-12-02).
        edge_segment_mm: longest segment of the edge models (mm; 3; 2026-12-04 eighth session).
        center_weight: weight of the centre term in every cost (pixels; 1, the paper's 0; 2026-12-03 second session).
        seed: seed of the candidates, with the object's index (integer; 0).
        backend: the code of every render and cost (``auto``: numba's loops on the CPU and kernels on CUDA, torch
            where they cannot run; ``torch``; ``numba``, which fails where numba cannot run at all; the same rows to float32
            rounding, :mod:`bop_cender.pose.backend`; ``docs/performance.md``).
        candidates, refine, screen, sweeps, scene_polish, network: the sections above.
    """

    t_b: float = 0.75
    occlusion: bool = True
    search_cost: str = "edges"
    edge_segment_mm: float = 3.0
    center_weight: float = 1.0
    seed: int = 0
    backend: str = "auto"
    candidates: CandidateSettings = field(default_factory=CandidateSettings)
    refine: RefineSettings = field(default_factory=RefineSettings)
    screen: ScreenSettings = field(default_factory=ScreenSettings)
    sweeps: SweepSettings = field(default_factory=SweepSettings)
    scene_polish: ScenePolishSettings = field(default_factory=ScenePolishSettings)
    network: NetworkSettings = field(default_factory=NetworkSettings)

    def for_network_centers(self) -> PoseConfig:
        """This config with the ``network`` section's candidates' spread, refinement box and scene-polish passes
        where set: what stage 3 uses when the 3D centres come from a network."""
        net = self.network
        return replace(
            self,
            candidates=_where_set(self.candidates, translation_sigma_mm=net.translation_sigma_mm),
            refine=_where_set(self.refine, translation_bound_mm=net.translation_bound_mm),
            scene_polish=_where_set(self.scene_polish, passes=net.scene_polish_passes),
        )

    def check_refinable(self, field: str) -> None:
        """Refuse more starts to refine than candidates (``top_k`` > ``n``): the refinement would run fewer than
        asked. Not in :meth:`__post_init__`: ``--set`` applies one setting at a time, and the two may come in either
        order; checked once all are in, by ``run`` (``field``: the option to name).

        Raises:
            ConfigError: naming ``field``.
        """
        if self.candidates.top_k > self.candidates.n:
            raise ConfigError(
                f"refines the best {self.candidates.top_k} (poses.candidates.top_k) of {self.candidates.n} candidates"
                " (poses.candidates.n): give at least as many candidates as starts to refine",
                field=field,
            )

    def __post_init__(self) -> None:
        """Every setting of every section is checked here (named choices, types and ranges), so that a bad ``--set``
        is one error before any scene runs."""
        for name, allowed in (("search_cost", SEARCH_COSTS), ("backend", BACKEND_NAMES)):
            if getattr(self, name) not in allowed:
                raise ConfigError(
                    f"poses.{name}: expected one of {', '.join(allowed)}, got {getattr(self, name)!r}", field="--set"
                )
        check_settings("poses", self, _POSES, flags=("occlusion",))
        for name, kind, bounds in _SECTIONS:
            section: object = self
            for part in name.split("."):
                section = getattr(section, part)
            if not isinstance(section, kind):
                raise ConfigError(f"poses.{name}: expected a {kind.__name__}, got {section!r}", field="--set")
            check_settings(f"poses.{name}", section, bounds, flags=_SECTION_FLAGS.get(name, ()))


_POSES = {
    "t_b": _UNIT_INTERVAL,
    "edge_segment_mm": POSITIVE,
    "center_weight": NON_NEGATIVE,
    "seed": Bound(0, integer=True),
}
"""What each top-level stage-3 setting may be (:func:`~bop_cender.settings_checks.check_settings`)."""

#: Every section (its path below ``poses``, its type, what each of its fields may be), parents before children.
_SECTIONS: tuple[tuple[str, type, Mapping[str, Bound]], ...] = (
    ("candidates", CandidateSettings, _CANDIDATES),
    ("refine", RefineSettings, _REFINE),
    ("refine.nelder_mead", NelderMead, _REFINE_NELDER_MEAD),
    ("screen", ScreenSettings, {"starts": COUNT_OR_ZERO}),
    ("screen.nelder_mead", NelderMead, _NELDER_MEAD),
    ("sweeps", SweepSettings, {"passes": COUNT}),
    ("scene_polish", ScenePolishSettings, _SCENE_POLISH),
    ("scene_polish.nelder_mead", NelderMead, _NELDER_MEAD),
    ("network", NetworkSettings, _NETWORK),
)


#: The bool fields of a section (checked as flags).
_SECTION_FLAGS: dict[str, tuple[str, ...]] = {"candidates": ("symmetric_separation",)}


def _where_set(section: object, **values: object) -> object:
    """``section`` with the fields of ``values`` that are not None replaced."""
    return replace(section, **{k: v for k, v in values.items() if v is not None})


#: Named starting points of the config (``run --preset``), as settings below ``poses`` applied after the dataset's
#: layout and before ``--set``. ``ours``: the defaults above. ``paper``: the paper's stage 3, one sweep without the
#: scene polish, the centre term or the screen; the search stays on the edge proxy and every object's final cost
#: is the paper's render cost (``poses.search_cost=render`` renders every evaluation too: the same 17 of 21 parts
#: placed, 3-5x the time, 2026-12-02). Its figures: the eighteenth session's table, "the paper's stage 3".
PRESETS: dict[str, tuple[str, ...]] = {
    "ours": (),
    "paper": ("sweeps.passes=1", "scene_polish.nelder_mead.maxfev=0", "center_weight=0", "screen.starts=0"),
}
