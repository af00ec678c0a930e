"""Session fixtures for the scoring tests: one small T-LESS-layout fixture (and its DIMO copy), built once."""

from __future__ import annotations

from pathlib import Path

import pytest

from bop_cender.data.registry import DatasetRequest, open_dataset
from bop_cender.synth.regression_fixture import BuiltFixture, build_fixture
from tests.eval.scoring_data import SMALL, write_dimo_copy


@pytest.fixture(scope="session")
def small_fixture(tmp_path_factory: pytest.TempPathFactory) -> BuiltFixture:
    """2 scenes x 3 images at 240x180, rendered depth, targets for 2 of 3 images per scene (the third is on disk, not a target)."""
    return build_fixture(tmp_path_factory.mktemp("tless_small") / "tless", SMALL)


@pytest.fixture()
def small_dataset(small_fixture: BuiltFixture):
    return open_dataset(DatasetRequest("tless", small_fixture.root, "test"))


@pytest.fixture(scope="session")
def dimo_copy(small_fixture: BuiltFixture, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_dimo_copy(small_fixture, tmp_path_factory.mktemp("dimo_small"))


@pytest.fixture()
def results_dir(tmp_path: Path) -> Path:
    out = tmp_path / "results"
    out.mkdir()
    return out
