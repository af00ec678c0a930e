"""Where the data comes from when the user names none: the embedded demo, resolved above both layers.

The data layer (:mod:`bop_cender.data`) opens what is on disk; the synthetic generator
(:mod:`bop_cender.synth`) writes datasets. This module, used by the CLI and the runner, sits above both:
with no data root, ``dimo`` and ``tless`` resolve to the embedded demo (generated once into the cache,
:mod:`bop_cender.synth.demo`). It prints nothing itself: ``announce`` receives one line per event and
the caller decides where it goes (the CLI: stderr).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from bop_cender.data.registry import DatasetRequest, open_dataset
from bop_cender.data.types import Dataset
from bop_cender.errors import ConfigError

#: Layouts that have an embedded demo.
DEMO_LAYOUTS = ("dimo", "tless")


def resolve_data_root(
    dataset: str, data_root: str | Path | None, announce: Callable[[str], None] | None = None
) -> Path:
    """The data root to open: ``data_root`` when given, else the embedded demo of ``dataset``.

    Args:
        dataset: ``dimo``, ``tless``, ``bop`` or a BOP dataset name.
        data_root: what the user gave (None: nothing).
        announce: called with a line when the demo is used (and when it is generated first).

    Raises:
        ConfigError: no data root for a dataset without a demo.
    """
    if data_root is not None:
        return Path(data_root)
    if dataset not in DEMO_LAYOUTS:
        raise ConfigError(
            f"--dataset {dataset} needs --data-root DIR (a folder in the BOP layout)", field="--data-root"
        )
    from bop_cender.synth.demo import ensure_demo

    root = ensure_demo(dataset, announce=announce)
    if announce is not None:
        announce(f"no --data-root: using the embedded synthetic {dataset} demo at {root}")
    return root


def open_with_demo(request: DatasetRequest, announce: Callable[[str], None] | None = None) -> Dataset:
    """:func:`~bop_cender.data.registry.open_dataset`, with no root resolved to the embedded demo."""
    return open_dataset(replace(request, root=resolve_data_root(request.dataset, request.root, announce)))


def is_demo_root(dataset: str, root: str | Path) -> bool:
    """Whether ``root`` is where the embedded demo of ``dataset`` lives (a run on the demo names it in its sidecar)."""
    if dataset not in DEMO_LAYOUTS:
        return False
    from bop_cender.synth.demo import demo_root

    return Path(root).expanduser().resolve() == demo_root(dataset).expanduser().resolve()


def open_results_data(
    request: DatasetRequest, *, demo: bool = False, announce: Callable[[str], None] | None = None
) -> Dataset:
    """Open the data a results file is scored on, using the embedded demo only where the user asked for it.

    Results scored on data they were not made on give a meaningless score (every row ignored), so a
    missing data root is not quietly replaced by the demo, as it is for ``run`` or ``info``. The user
    asks for the demo with ``demo`` (``--demo``), or by scoring a run made on it (its sidecar names the
    demo's root, regenerated here if the cache was cleared).

    Raises:
        ConfigError: no root and no ``demo``, or ``demo`` for a dataset without one.
    """
    if demo:
        return open_dataset(replace(request, root=resolve_data_root(request.dataset, None, announce)))
    if request.root is None:
        raise ConfigError(
            "no data root (no --data-root, and no run sidecar naming one): give --data-root DIR, the dataset the "
            f"results were made on, or --demo to score against the embedded synthetic {request.dataset} demo",
            field="--data-root",
        )
    if is_demo_root(request.dataset, request.root):
        from bop_cender.synth.demo import ensure_demo

        ensure_demo(request.dataset, announce=announce)
    return open_dataset(request)
