"""``scripts/bench_run.py --profile``: the counts behind the claim that a small GPU cost call is host-bound."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parents[1] / "scripts"))
import bench_run  # noqa: E402


def test_a_cost_call_is_profiled_into_time_operators_launches_and_syncs(device) -> None:
    (row,) = bench_run.cost_call_profile(device, batches=(1,))
    batch, ms, ops, launches, syncs = row
    assert batch == 1 and ms > 0 and ops > 100  # the candidate path runs many small operators per call
    assert (launches > 0) == (device.type == "cuda") and syncs > 0  # nonzero compactions at least
