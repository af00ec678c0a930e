"""How a CUDA kernel stands in a process (``cuda_loops.KernelGuard``): run where it can, else the caller's torch path.

Every CUDA kernel of stage 3 and the renderer goes through one guard: where numba's CUDA target is missing (no
numba-cuda, no driver), where the kernel failed to compile or launch (numba's or the driver's error: for the rest of
the process), or where one call failed on its own (out of memory: that call only), its caller takes its torch path
after one warning; ``insist`` (the backend named ``numba``) raises instead. Tested with stand-in computations: no GPU needed.
"""

from __future__ import annotations

import warnings

import pytest
import torch
from numba.core.errors import NumbaError

from bop_cender.render.cuda_loops import KernelGuard, check_device, check_threads, is_kernel_error


def _guard() -> KernelGuard:
    return KernelGuard("the CUDA test kernel", "the test runs its torch path on CUDA", lambda: None)


def _raising(error: Exception):
    def compute():
        raise error

    return compute


def test_an_available_kernel_runs_and_what_it_returns_is_the_callers(kernel_standing) -> None:
    guard = _guard()
    kernel_standing(guard)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing to warn about
        assert guard.run(lambda: 7) == 7 == guard.run(lambda: 7, insist=True)
        assert guard.run(lambda: None) is None  # the kernel does not apply: the caller's torch path
    assert guard.unavailable() is None


def test_without_numbas_cuda_target_the_torch_path_serves_after_one_warning(kernel_standing) -> None:
    guard = _guard()
    kernel_standing(guard, "numba.cuda finds no CUDA driver or device")
    with pytest.warns(RuntimeWarning, match="the test runs its torch path on CUDA: numba.cuda finds no CUDA driver"):
        assert guard.run(lambda: 7) is None
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert guard.run(lambda: 7) is None  # warned once
    with pytest.raises(
        RuntimeError,
        match=r"needs the CUDA test kernel, which cannot run here: numba.cuda finds .* \(pip install numba-cuda\)",
    ):
        guard.run(lambda: 7, insist=True)


def test_a_calls_own_failure_costs_that_call_a_kernel_failure_the_process(kernel_standing) -> None:
    guard = _guard()
    kernel_standing(guard)
    out_of_memory = torch.cuda.OutOfMemoryError("CUDA out of memory")
    with pytest.warns(RuntimeWarning, match="for a call: the CUDA test kernel's call failed .OutOfMemoryError"):
        assert guard.run(_raising(out_of_memory)) is None
    assert guard.failed == [] and guard.run(lambda: 7) == 7  # the next call takes the kernel again
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the same kind of failure again, another size: not warned again
        assert guard.run(_raising(torch.cuda.OutOfMemoryError("Tried to allocate 2.00 GiB"))) is None
    with pytest.raises(torch.cuda.OutOfMemoryError):
        guard.run(_raising(out_of_memory), insist=True)
    nvvm = NumbaError("NVVM_ERROR_COMPILATION")
    with pytest.raises(NumbaError):
        guard.run(_raising(nvvm), insist=True)  # insisting: raised, nothing recorded
    assert guard.failed == []
    with pytest.warns(RuntimeWarning, match=r"torch path on CUDA: the CUDA test kernel failed \(NumbaError: NVVM"):
        assert guard.run(_raising(nvvm)) is None
    assert guard.run(lambda: 7) is None  # the rest of the process stays on the torch path
    with pytest.raises(
        RuntimeError, match="needs the CUDA test kernel, which cannot run here: the CUDA test kernel failed"
    ) as raised:
        guard.run(lambda: 7, insist=True)
    assert "pip install" not in str(raised.value)  # numba-cuda is there: installing it is no advice


def test_kernel_errors_are_numbas_or_the_drivers() -> None:
    assert is_kernel_error(NumbaError("x"))
    assert not is_kernel_error(RuntimeError("x")) and not is_kernel_error(torch.cuda.OutOfMemoryError("x"))


@pytest.mark.parametrize("threads", [0, 3, 256])
def test_a_block_size_is_a_power_of_two_up_to_the_limit(threads: int) -> None:
    with pytest.raises(ValueError, match="power of two up to 128"):
        check_threads(threads, 128)
    check_threads(64, 128)


def test_the_kernels_refuse_cpu_tensors_outside_the_simulator() -> None:
    from bop_cender.render.cuda_loops import simulator_enabled

    if simulator_enabled():
        pytest.skip("the simulator takes CPU tensors")
    with pytest.raises(ValueError, match="the CUDA test kernel takes CUDA tensors"):
        check_device(torch.device("cpu"), "the CUDA test kernel")


def test_every_kernel_name_is_visible_to_a_reader() -> None:
    """The kernels are closures of factories over their device functions (``render/cuda_device.py``): no function is
    rebuilt from a code object with other globals at run time, and no name is left for ruff to be told to ignore."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    for path in sorted([*(root / "bop_cender").rglob("*.py"), *(root / "scripts").glob("*.py")]):
        text = path.read_text()
        assert "noqa: F821" not in text, path
        assert "FunctionType(" not in text and "__code__" not in text, path
