"""The stage-3 tests' scene: the method's small two-part scene with its oracle curvature and distance maps."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parents[1]))
import method_data  # noqa: E402


@pytest.fixture(scope="module")
def mini(tmp_path_factory):
    """``(dataset, scene, meshes, oracle maps, cameras, distance maps)`` of the method's test scene
    (:func:`method_data.mini_scene`)."""
    return method_data.mini_scene(tmp_path_factory.mktemp("mini") / "dimo")
