"""The scoring tests' fixtures (a small rendered T-LESS-layout dataset and its DIMO copy), shared here."""

from tests.eval.conftest import dimo_copy, results_dir, small_dataset, small_fixture  # noqa: F401  (pytest fixtures)
