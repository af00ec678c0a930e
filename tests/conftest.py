"""Fixtures shared by every test folder."""

import pytest
import torch

#: CPU always; CUDA where present (skipped otherwise), as kornia parametrises its tests.
DEVICES = ["cpu", pytest.param("cuda", marks=pytest.mark.cuda)]


@pytest.fixture(params=DEVICES)
def device(request) -> torch.device:
    """Each device the tensor code must run on: the device follows the inputs."""
    if request.param == "cuda" and not torch.cuda.is_available():
        pytest.skip("no CUDA device")
    return torch.device(request.param)


@pytest.fixture()
def on_one_and_two_threads():
    """``run(call)`` -> ``(call() on one torch thread, call() on two)``, torch's count restored after: the compiled
    loops run serial on one thread and threaded on more, and must give the same bits."""

    def run(call):
        before = torch.get_num_threads()
        try:
            torch.set_num_threads(1)
            one = call()
            torch.set_num_threads(2)
            return one, call()
        finally:
            torch.set_num_threads(before)

    return run


@pytest.fixture()
def kernel_standing(monkeypatch):
    """``set(guard, unavailable=None)``: a CUDA kernel's :class:`~bop_cender.render.cuda_loops.KernelGuard` with a
    fresh standing (no failure recorded, nothing warned yet) and numba's CUDA target as asked (None: it works; a
    string: why not), all undone after the test."""
    from bop_cender.render import cuda_loops

    def set_standing(guard, unavailable: str | None = None) -> None:
        monkeypatch.setattr(guard, "failed", [])
        monkeypatch.setattr(guard, "_warned", set())
        monkeypatch.setattr(cuda_loops, "cuda_unavailable_reason", lambda: unavailable)

    return set_standing
