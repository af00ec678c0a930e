"""Who renders the VSD depth crops: worker threads of this process, or a forked render process.

Why a process: a cold ``bop-cender score`` spends about 1 s importing torch, on one core, before the
first render. Forked at the start of scoring, before this process imports torch, a child imports it
and then renders while this process reads the data and computes MSSD, MSPD and the VSD of the crops
already rendered: the import leaves the critical path and both cores work from the first second.
Where the child cannot help (no ``fork``, or torch is already imported, so there is no import to
overlap) the threads of this process render, as a library caller gets by default.

A child is forked only while torch is not imported here. Forking a process whose torch has run (MKL's
allocator and the OpenMP pool copied mid-use) can leave the child spinning for ever in
``mkl_serv_allocate`` (seen in CI: a render test hung for 90 minutes), so a render process started
after torch's import is spawned instead: it imports torch afresh, one second later, and is safe.

Both renderers take a list of :class:`RenderJob` and yield ``(job index, DepthCrops)`` in the order
the jobs finish, so that the caller computes VSD image by image as their renders arrive. The crops
are those of :func:`bop_cender.eval.depth_render.render_depth_crops` either way, bit for bit.

If the child dies (killed, out of memory) or fails, the jobs it has not returned are rendered in
this process, with a warning: the scores never depend on which path rendered them.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import queue
import sys
import threading
import traceback
import warnings
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Executor, Future, wait
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol

if TYPE_CHECKING:  # only the standard library at import: the CLI forks the child before heavier imports
    import numpy as np

    from bop_cender.eval.render_crops import DepthCrops
    from bop_cender.meshes import MeshCache
    from bop_cender.render.mesh import RenderMesh

__all__ = ["AHEAD", "RenderJob", "DepthRenderer", "ThreadRenderer", "RenderProcess", "render_process_useful"]

#: Jobs rendered ahead of the caller at most (bounded memory when the caller is slower than the renders).
AHEAD = 16


@dataclass(frozen=True)
class RenderJob:
    """n poses of one object to render as depth crops in images of one size.

    Attributes:
        obj_id: the object (a key of the :class:`~bop_cender.meshes.MeshCache`).
        T_cam_model: ``(n, 4, 4)`` float64 model-to-camera poses (mm).
        K: ``(n, 3, 3)`` float64 intrinsics, one per pose.
        height, width: image size (pixels beyond it are dropped).
    """

    obj_id: int
    T_cam_model: np.ndarray
    K: np.ndarray
    height: int
    width: int

    def __len__(self) -> int:
        return len(self.T_cam_model)


class DepthRenderer(Protocol):
    """Renders jobs, yielding ``(index into jobs, crops)`` as each job finishes (any order, each once)."""

    def render(self, jobs: Sequence[RenderJob], meshes: MeshCache) -> Iterator[tuple[int, DepthCrops]]: ...

    def describe(self) -> str:
        """Who rendered, in a few words (for the scores' metadata)."""
        ...


def render_job(job: RenderJob, meshes: MeshCache | Callable[[int], RenderMesh]) -> DepthCrops:
    """One job, in this thread (imports the renderer, hence torch); ``meshes(obj_id)`` gives the render mesh."""
    from bop_cender.eval.depth_render import render_depth_crops

    return render_depth_crops(meshes(job.obj_id), job.T_cam_model, job.K, job.height, job.width)


@dataclass
class ThreadRenderer:
    """Renders on the threads of an executor of this process (the caller keeps torch to one intra-op thread)."""

    pool: Executor

    def describe(self) -> str:
        return "threads of the scoring process"

    def render(self, jobs: Sequence[RenderJob], meshes: MeshCache) -> Iterator[tuple[int, DepthCrops]]:
        from bop_cender.eval.depth_render import render_depth_crops

        prepared = {o: meshes(o) for o in sorted({j.obj_id for j in jobs})}  # here: the cache is not thread-safe
        pending: dict[Future, int] = {}
        submitted = 0
        try:
            while pending or submitted < len(jobs):
                # At most AHEAD jobs rendered but not yet taken: memory stays bounded if VSD falls behind.
                while submitted < len(jobs) and len(pending) < AHEAD:
                    job = jobs[submitted]
                    mesh = prepared[job.obj_id]
                    future = self.pool.submit(render_depth_crops, mesh, job.T_cam_model, job.K, job.height, job.width)
                    pending[future] = submitted
                    submitted += 1
                finished, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in finished:
                    yield pending.pop(future), future.result()
        finally:  # an abandoned iteration (an error downstream) leaves no renders queued behind it
            for future in pending:
                future.cancel()


def render_process_useful() -> bool:
    """Whether a forked render process would shorten scoring: on Linux (where ``fork`` is safe with the
    libraries we load; macOS's system frameworks are not) and while torch is not imported yet."""
    return sys.platform.startswith("linux") and "torch" not in sys.modules


class RenderProcess:
    """A forked child that imports torch and renders depth crops for this process (see the module docstring).

    Start it as early as possible (:meth:`start`), use it as a :class:`DepthRenderer`, close it (or use
    ``with``). Not thread-safe: one :meth:`render` at a time.
    """

    def __init__(self, process: multiprocessing.process.BaseProcess, conn, start_method: str = "fork") -> None:
        self._process = process
        self._conn = conn
        self._start_method = start_method
        self._closed = False
        self._stopped: str | None = None  # why the child stopped early, and how much was rendered here
        self._courier: threading.Thread | None = None

    @classmethod
    def start(cls) -> RenderProcess:
        """Start the child now (forked before torch's import, spawned after it); it imports torch at once and
        waits for jobs.

        Raises:
            ConfigError: this platform has no ``fork`` (Windows).
        """
        if "fork" not in multiprocessing.get_all_start_methods():
            from bop_cender.errors import ConfigError

            raise ConfigError("a render process needs fork(), which this platform lacks: render in threads instead")
        start_method = "spawn" if "torch" in sys.modules else "fork"  # see the module docstring
        ctx = multiprocessing.get_context(start_method)
        parent_conn, child_conn = ctx.Pipe(duplex=True)
        inherited = parent_conn if start_method == "fork" else None  # a forked child holds both ends: it closes ours
        process = ctx.Process(target=_child_main, args=(child_conn, inherited), name="bop-cender-render", daemon=True)
        with warnings.catch_warnings():
            # Python >= 3.12 warns about forking while NumPy's BLAS threads exist (a library caller that imported
            # NumPy first). The child never calls BLAS, and OpenBLAS resets its pool in the child at fork anyway.
            warnings.filterwarnings(
                "ignore", message=r".*use of fork\(\) may lead to deadlocks", category=DeprecationWarning
            )
            process.start()
        child_conn.close()
        return cls(process, parent_conn, start_method)

    def __enter__(self) -> RenderProcess:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def describe(self) -> str:
        kind = "a forked render process" if self._start_method == "fork" else "a spawned render process"
        if self._stopped is not None:
            return f"{kind}, then the scoring process ({self._stopped})"
        return kind

    def close(self) -> None:
        """Stop the child (at once: it may still be importing torch) and reap it."""
        if self._closed:
            return
        self._closed = True
        with contextlib.suppress(OSError, ValueError):
            self._conn.send(None)
        self._process.join(timeout=0.05)
        if self._process.is_alive():
            self._process.terminate()
            self._process.join()
        if self._courier is not None:  # the child is gone, so its pipe is at EOF and the courier returns
            self._courier.join()
        self._conn.close()

    def render(self, jobs: Sequence[RenderJob], meshes: MeshCache) -> Iterator[tuple[int, DepthCrops]]:
        if not jobs:
            return
        if self._closed:
            raise RuntimeError("the render process is closed")
        # Plain arrays, not MeshArrays: unpickling that class would import its module's dependencies (SciPy)
        # in the child, on its critical path.
        arrays = {o: _Mesh(meshes.arrays(o).vertices, meshes.arrays(o).faces) for o in sorted({j.obj_id for j in jobs})}
        inbox: queue.Queue = queue.Queue(maxsize=AHEAD)  # full: the courier stops reading, the child waits
        stop = threading.Event()
        # Sending may wait for the child to finish importing torch, and the child's replies must be read
        # while this thread computes: one helper thread does both, so this one never blocks on the pipe.
        courier = threading.Thread(
            target=self._exchange, args=(arrays, list(jobs), inbox, stop), name="bop-cender-render-io", daemon=True
        )
        courier.start()
        self._courier = courier
        done: set[int] = set()
        failure = None
        try:
            while len(done) < len(jobs):
                kind, payload = inbox.get()
                if kind != "crops":
                    failure = payload
                    break
                index, crops = payload
                done.add(index)
                yield index, crops
        finally:
            if len(done) < len(jobs) and failure is None:  # abandoned (an error downstream): replies would go stale
                stop.set()
                self.close()
        courier.join()
        if failure is None:
            return
        self.close()
        missing = [i for i in range(len(jobs)) if i not in done]
        self._stopped = f"the render process stopped; {len(missing)} of {len(jobs)} jobs rendered here"
        warnings.warn(
            f"the render process stopped ({failure}); rendering its last {len(missing)} of {len(jobs)} jobs here",
            RuntimeWarning,
            stacklevel=2,
        )
        for i in missing:
            yield i, render_job(jobs[i], meshes)

    def _exchange(
        self, arrays: dict[int, _Mesh], jobs: list[RenderJob], inbox: queue.Queue, stop: threading.Event
    ) -> None:
        """Courier thread: send the work, then pass every reply to ``inbox`` until all jobs are back, the child
        fails, or ``stop`` is set (the caller gave up)."""

        def deliver(item: tuple) -> bool:
            while not stop.is_set():
                try:
                    inbox.put(item, timeout=0.1)
                    return True
                except queue.Full:
                    continue
            return False

        try:
            self._conn.send(("work", arrays, jobs))
            for _ in jobs:
                reply = self._conn.recv()
                if reply[0] != "crops":
                    deliver(("failed", f"it raised:\n{reply[1]}"))
                    return
                if not deliver(("crops", (reply[1], reply[2]))):
                    return
        except (EOFError, OSError) as exc:
            if stop.is_set():
                return
            self._process.join(timeout=1.0)  # reap a dead child, for its exit code
            code = self._process.exitcode
            deliver(("failed", f"{type(exc).__name__}, exit code {code}" if code is not None else repr(exc)))


def _child_main(conn, parent_end) -> None:
    """The child: import torch (one intra-op thread), then render each job received and send its crops.

    ``parent_end`` is the parent's end of the pipe where the child was forked (closed here, so that the
    child sees EOF when the parent goes), None where it was spawned."""
    if parent_end is not None:
        parent_end.close()
    try:
        import torch

        torch.set_num_threads(1)
        from bop_cender.render.mesh import prepare_mesh

        while True:
            message = conn.recv()
            if message is None:
                return
            _, arrays, jobs = message
            meshes = _PreparedMeshes({o: prepare_mesh(a) for o, a in arrays.items()})
            for index, job in enumerate(jobs):
                conn.send(("crops", index, render_job(job, meshes)))
    except (EOFError, BrokenPipeError, KeyboardInterrupt):
        return
    except BaseException:  # noqa: BLE001 - reported to the parent, which renders the rest itself
        with contextlib.suppress(OSError):
            conn.send(("error", traceback.format_exc()))


class _Mesh(NamedTuple):
    """A mesh as sent to the child: ``vertices (N, 3)`` float64, ``faces (F, 3)`` int64 (what prepare_mesh reads)."""

    vertices: Any
    faces: Any


@dataclass
class _PreparedMeshes:
    """Render meshes already prepared, called like :class:`~bop_cender.meshes.MeshCache`."""

    meshes: dict[int, RenderMesh]

    def __call__(self, obj_id: int) -> RenderMesh:
        return self.meshes[obj_id]
