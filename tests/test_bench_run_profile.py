"""``scripts/bench_run.py --profile``: the counts behind the claim that a small GPU cost call is host-bound."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parents[1] / "scripts"))
import bench_run  # noqa: E402


def test_a_cost_call_is_profiled_into_time_operators_launches_and_syncs(device) -> None:
    (row,) = bench_run.cost_call_profile(device, batches=(1,), backend="torch")
    batch, ms, ops, launches, syncs = row
    assert batch == "1, torch atlases" and ms > 0 and ops > 100  # the atlases run many small operators per call
    assert (launches > 0) == (device.type == "cuda") and syncs > 0  # nonzero compactions at least
    (default,) = bench_run.cost_call_profile(device, batches=(1,))
    assert default[0] == "1, default" and default[2] < ops  # the compiled loop (CPU) or kernel (CUDA): fewer operators
    if device.type == "cuda":
        assert default[4] < syncs  # the kernel waits for the device once per call


def test_an_edge_call_is_profiled_in_every_layout_the_dense_one_never_synchronises_the_kernel_runs_no_operator(
    device,
) -> None:
    rows = bench_run.edge_call_profile(device, batch=2)
    assert [r[0] for r in rows] == ["compacted", "dense"] + (["kernel"] if device.type == "cpu" else [])
    (_, _, ops_c, _, syncs_c), (_, ms, ops_d, launches, syncs_d) = rows[:2]
    assert ms > 0 and ops_d > 10 and (launches > 0) == (device.type == "cuda")
    assert syncs_c > 0 and syncs_d == 0
    if device.type == "cpu":
        _, ms_k, ops_k, _, syncs_k = rows[2]
        assert ms_k > 0 and ops_k < ops_c / 3 and syncs_k == 0  # conversions around one compiled call


def test_an_unknown_device_is_one_usage_error() -> None:
    import subprocess

    done = subprocess.run(
        [sys.executable, str(Path(__file__).parents[1] / "scripts" / "bench_run.py"), "--devices", "gpu"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2 and "--devices 'gpu': expected cpu and/or cuda" in done.stderr
    assert "Traceback" not in done.stderr


def test_the_benchmark_asks_the_cuda_edge_kernels_guard_whether_it_runs(monkeypatch) -> None:
    """The CUDA rows of the edge proxy ask the kernel's guard (the branch no CPU run takes: a removed name there once
    broke the benchmark on GPUs only)."""
    from bop_cender.pose import cuda_edge_kernel

    monkeypatch.setattr(cuda_edge_kernel.GUARD, "unavailable", lambda: None)
    assert bench_run._cuda_edge_kernel_unavailable() is None
    monkeypatch.setattr(cuda_edge_kernel.GUARD, "unavailable", lambda: "no driver")
    assert bench_run._cuda_edge_kernel_unavailable() == "no driver"
