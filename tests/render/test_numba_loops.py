"""numba_loops.canvas_loop: the serial/threaded pair, and a machine where no cache folder is writable."""

from __future__ import annotations

import numba
import numpy as np
import torch

from bop_cender.render import numba_loops


def _squares(x, out):
    for i in numba.prange(x.shape[0]):
        out[i] = x[i] * x[i]


def test_without_a_writable_cache_the_loop_is_compiled_uncached(monkeypatch):
    """numba raises "cannot cache function ... no locator available" where no cache folder is writable (a read-only
    install, no writable home): the loop still compiles, uncached, instead of the CPU default failing."""
    real = numba.njit

    def njit(*args, **flags):
        if flags.get("cache"):
            raise RuntimeError("cannot cache function '_squares': no locator available for file 'x.py'")
        return real(*args, **flags)

    monkeypatch.setattr(numba_loops.numba, "njit", njit)
    loop = numba_loops.canvas_loop(_squares)
    out = np.zeros(4)
    threads = torch.get_num_threads()
    try:
        for n in (1, 2):
            torch.set_num_threads(n)
            loop(np.arange(4.0), out)
            assert out.tolist() == [0.0, 1.0, 4.0, 9.0]
    finally:
        torch.set_num_threads(threads)
    assert numba.get_num_threads() == numba.config.NUMBA_NUM_THREADS  # the threaded call left numba's setting alone


def test_compiled_threads_run_the_threaded_loop_and_leave_torch_on_its_thread_count() -> None:
    """Inside ``compiled_threads(2)`` the loops run threaded whatever torch's count; afterwards torch still has its
    one thread (numba's OpenMP layer shares the runtime with torch and left it on 2: torch's sums then changed)."""
    import numba
    import numpy as np
    import torch

    def squares(x, out):
        for i in numba.prange(x.shape[0]):
            out[i] = x[i] * x[i]
        return 0

    loop = numba_loops.canvas_loop(squares)
    x = np.arange(64, dtype=np.float64)
    out = np.empty_like(x)
    before = torch.get_num_threads()
    calls = []
    real_set = numba.set_num_threads
    try:
        torch.set_num_threads(1)
        numba.set_num_threads = lambda n: (calls.append(n), real_set(n))[1]  # the threaded path sets it
        loop(x, out)
        assert calls == []  # torch's one thread: the serial loop
        with numba_loops.compiled_threads(2):
            with numba_loops.compiled_threads(1):
                loop(x, out)
            assert calls == []
            loop(x, out)
        assert calls[:1] == ([2] if numba.config.NUMBA_NUM_THREADS >= 2 else []), calls
        assert np.array_equal(out, x * x) and numba_loops._THREADS == []
        assert torch.get_num_threads() == 1
    finally:
        numba.set_num_threads = real_set
        torch.set_num_threads(before)
