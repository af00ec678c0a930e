"""What the compiled CPU loops share (the renderer's and stage 3's): one loop compiled twice (serial and threaded), NumPy views of tensors.

Why two compilations. A loop over canvases written with ``numba.prange`` can run on threads, but numba's OpenMP
pool, once started, keeps its idle threads spinning between parallel regions; stage 3 calls its loops thousands
of times a second, so with ``run --workers 2`` on 2 cores each process's idle OpenMP thread took half a core
from the other process's work (50 % system time, every scene about twice as slow). With one thread (what ``run``
gives each process: :func:`torch.get_num_threads` is 1 there) the serial version runs and no pool is ever
started; with more, the threaded one, each canvas summed by one thread in the same order, so both give the
same bits.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numba
import numpy as np
import torch

from bop_cender.render.numba_cache import cached_njit

#: The compiled loops' thread count while :func:`compiled_threads` is in force (empty: torch's thread count).
_THREADS: list[int] = []


@contextmanager
def compiled_threads(threads: int) -> Iterator[None]:
    """Run the compiled loops on ``threads`` threads inside the block, whatever torch's thread count (``run
    --threads``: one process keeps one torch thread, for torch's small operators, and gives the loops the cores)."""
    _THREADS.append(int(threads))
    try:
        yield
    finally:
        _THREADS.pop()


def canvas_loop(py_func: Callable | None = None, *, error_model: str = "python") -> Callable:
    """``py_func`` (a loop over canvases with ``numba.prange``) compiled serial and threaded; the returned function
    runs the serial one where torch uses one thread, else the threaded one on torch's thread count (at most
    numba's). The serial version is cached on disk, in the folder of this version of the package's sources
    (:mod:`bop_cender.render.numba_cache`); the threaded one is compiled on first use in a process (not cached: the
    cache's index does not tell the two compilations of one function apart).

    ``error_model``: numba's (``"numpy"``: a float division by zero gives inf or NaN, as in torch, instead of
    raising); used as ``@canvas_loop(error_model="numpy")``."""
    if py_func is None:
        return lambda func: canvas_loop(func, error_model=error_model)
    serial = cached_njit(py_func, nogil=True, error_model=error_model)  # the package version's cache (numba_cache)
    threaded = numba.njit(nogil=True, parallel=True, error_model=error_model)(py_func)

    def run(*args):
        torch_threads = torch.get_num_threads()
        threads = min(_THREADS[-1] if _THREADS else torch_threads, numba.config.NUMBA_NUM_THREADS)
        if threads <= 1:
            return serial(*args)
        before = numba.get_num_threads()
        numba.set_num_threads(threads)
        try:
            return threaded(*args)
        finally:
            numba.set_num_threads(before)  # numba's setting is per thread: leave it as found
            # numba's OpenMP layer shares the runtime with torch: its parallel region leaves torch on its thread count
            # (1 -> 2 measured), and torch's reductions then sum in another order (other bits) and fight for cores
            if torch.get_num_threads() != torch_threads:
                torch.set_num_threads(torch_threads)

    run.__doc__ = py_func.__doc__
    run.serial, run.threaded = serial, threaded
    return run


def as_numpy(x: torch.Tensor) -> np.ndarray:
    """A CPU tensor's data as a C-contiguous NumPy array (no copy where it is contiguous already)."""
    return np.ascontiguousarray(x.detach().numpy())
