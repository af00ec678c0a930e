"""bop-cender: CenDerNet multi-view 6D pose estimation as a BOP method, with its own BOP harness.

The public API for scripts is what ``from bop_cender import ...`` gives (:data:`__all__`, documented with two
runnable examples in ``docs/api.md``): open a dataset, the method and its config, estimate one scene, read and
write BOP results, score a results file. Everything else is importable from its module but may move.

The names are imported on first use (:func:`__getattr__`), not here: most of them import torch (about a second),
and every ``bop-cender`` command imports this package first; ``score`` forks its render process before torch is
imported (``bop_cender/eval/render_process.py``), which an eager import here would defeat.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

__version__ = "0.1.0"

#: Each public name and the module that defines it (modules that stay where they are: not ``pose/``); the same names
#: as ``__all__`` and the imports for type checkers below (tests/test_public_api.py checks the three agree).
_HOMES = {
    # data
    "DatasetRequest": "bop_cender.data.registry",
    "open_with_demo": "bop_cender.datasets",
    "Dataset": "bop_cender.data.types",
    "Scene": "bop_cender.data.types",
    # the method
    "CenDerNet": "bop_cender.method",
    "CenDerNetConfig": "bop_cender.method",
    "OraclePredictor": "bop_cender.net.oracle",
    "NetPredictor": "bop_cender.net.predictor",
    "load_weights": "bop_cender.net.weights",
    "shipped_weights_path": "bop_cender.net.weights",
    "MeshCache": "bop_cender.meshes",
    "SceneEstimate": "bop_cender.estimates",
    "ObjectEstimate": "bop_cender.estimates",
    # results
    "BopEstimate": "bop_cender.results.bop_csv",
    "scene_estimates_to_rows": "bop_cender.results.bop_csv",
    "write_bop_results": "bop_cender.results.bop_csv",
    "read_bop_results": "bop_cender.results.bop_csv",
    "write_run_sidecar": "bop_cender.results.files",
    # scoring
    "score_file": "bop_cender.eval.score_file",
    # errors
    "BopCenderError": "bop_cender.errors",
}

__all__ = [
    "__version__",
    "DatasetRequest",
    "open_with_demo",
    "Dataset",
    "Scene",
    "CenDerNet",
    "CenDerNetConfig",
    "OraclePredictor",
    "NetPredictor",
    "load_weights",
    "shipped_weights_path",
    "MeshCache",
    "SceneEstimate",
    "ObjectEstimate",
    "BopEstimate",
    "scene_estimates_to_rows",
    "write_bop_results",
    "read_bop_results",
    "write_run_sidecar",
    "score_file",
    "BopCenderError",
]

if TYPE_CHECKING:  # what type checkers and IDEs see; at run time the names come from __getattr__
    from bop_cender.data.registry import DatasetRequest
    from bop_cender.data.types import Dataset, Scene
    from bop_cender.datasets import open_with_demo
    from bop_cender.errors import BopCenderError
    from bop_cender.estimates import ObjectEstimate, SceneEstimate
    from bop_cender.eval.score_file import score_file
    from bop_cender.meshes import MeshCache
    from bop_cender.method import CenDerNet, CenDerNetConfig
    from bop_cender.net.oracle import OraclePredictor
    from bop_cender.net.predictor import NetPredictor
    from bop_cender.net.weights import load_weights, shipped_weights_path
    from bop_cender.results.bop_csv import BopEstimate, read_bop_results, scene_estimates_to_rows, write_bop_results
    from bop_cender.results.files import write_run_sidecar


def __getattr__(name: str) -> object:
    """Import a public name's module on first use and keep the name here (later lookups do not come back).

    Any other name raises AttributeError, so that ``from bop_cender import method`` still imports the submodule."""
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module 'bop_cender' has no attribute {name!r}")
    value = getattr(importlib.import_module(home), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_HOMES))
