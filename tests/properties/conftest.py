"""Hypothesis profiles of the property tests: ``fast`` (default, deterministic) and ``thorough``.

Select with the environment variable ``HYPOTHESIS_PROFILE`` (``HYPOTHESIS_PROFILE=thorough pytest tests/properties``).
``fast`` is derandomized, so CI draws the same examples on every run; ``thorough`` draws new ones each run and
prints the blob that reproduces a failure.
"""

from __future__ import annotations

import os

from hypothesis import HealthCheck, settings

_COMMON = {
    "deadline": None,  # file-system work: timings vary with the machine's load
    "database": None,  # nothing written into the repository
    "suppress_health_check": [HealthCheck.too_slow, HealthCheck.function_scoped_fixture, HealthCheck.data_too_large],
}
settings.register_profile("fast", max_examples=60, derandomize=True, **_COMMON)
settings.register_profile("thorough", max_examples=1000, derandomize=False, print_blob=True, **_COMMON)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "fast"))
