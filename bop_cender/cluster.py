"""Where ``run`` and ``synth`` do their work: this machine (``--executor local``) or a Ray cluster (``--executor ray``).

Ray is an optional dependency (``pip install -e ".[ray]"``): it is imported here only, when a command asks for it,
and its absence, or a cluster that does not answer, is one :class:`~bop_cender.errors.ConfigError` naming the option.
What both commands share on a cluster is here: joining it (:func:`ray_session`), one actor per worker, each built once
and kept for all its jobs (:func:`start_actors`), and the jobs handed out one at a time to whichever actor is free,
their results yielded as they finish (:func:`as_completed`). Ray does the scheduling, the placement of actors on the
nodes, and the retries of a job whose actor died (``max_task_retries``, the actor restarted: ``max_restarts``).

Docs: ``docs/cluster.md``.
"""

from __future__ import annotations

import logging
import os
import socket
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, TypeVar

from bop_cender.errors import ConfigError

#: Where the work can run: this machine (one process or ``--workers`` processes) or a Ray cluster.
EXECUTORS = ("local", "ray")

#: How many times Ray runs a job again whose actor died (killed, out of memory, its node lost), on the restarted actor.
TASK_RETRIES = 2

#: Seconds to wait for a ``--address HOST:PORT`` to accept a connection before saying it cannot be reached.
CONNECT_TIMEOUT_S = 5.0

INSTALL_HINT = 'pip install -e ".[ray]" (or pip install "ray>=2.9")'

Job = TypeVar("Job")


def check_executor(executor: str, address: str | None, workers: int | None) -> None:
    """The executor options of ``run`` and ``synth``, before any work: a known executor, ``--address`` only with Ray,
    at least one worker. Whether Ray is installed and the address answers is checked when the cluster is joined.

    Raises:
        ConfigError: naming ``--executor``, ``--address`` or ``--workers``.
    """
    if executor not in EXECUTORS:
        raise ConfigError(f"expected one of {', '.join(EXECUTORS)}, got {executor!r}", field="--executor")
    if address is not None and executor != "ray":
        raise ConfigError(f"--address {address} names a Ray cluster; add --executor ray", field="--address")
    if workers is not None and workers < 1:
        raise ConfigError(f"expected at least 1 worker, got {workers}", field="--workers")


def import_ray() -> Any:
    """The ``ray`` module.

    Raises:
        ConfigError: Ray is not installed (``--executor ray`` needs the ``ray`` extra).
    """
    try:
        import ray
    except ImportError:
        raise ConfigError(
            f"--executor ray needs Ray, which is not installed: {INSTALL_HINT}", field="--executor"
        ) from None
    return ray


def check_address(address: str | None) -> None:
    """``None`` (a Ray instance started here), ``auto`` (the one running on this machine) or ``HOST:PORT`` of a head
    node that accepts a connection: a wrong port would otherwise leave ``ray.init`` retrying for a minute.

    Raises:
        ConfigError: a malformed address, or a head that cannot be reached (``field``: ``--address``).
    """
    if address is None or address == "auto":
        return
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise ConfigError(f"expected auto or HOST:PORT (e.g. 10.0.0.5:6379), got {address!r}", field="--address")
    try:
        socket.create_connection((host, int(port)), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as e:
        raise ConfigError(
            f"cannot reach a Ray head at {address} ({e.strerror or e}); start one there with"
            f" `ray start --head --port={port}`, or give its address",
            field="--address",
        ) from None


@contextmanager
def ray_session(address: str | None) -> Iterator[Any]:
    """Ray, joined for the duration of the block: at ``address`` (:func:`check_address`), or a Ray instance started on
    this machine for the block (None), shut down after; a process already connected (``ray.init`` by a notebook or
    a test) is used as it is and left connected.

    Raises:
        ConfigError: Ray not installed, or the cluster cannot be reached or joined.
    """
    ray = import_ray()
    if ray.is_initialized():
        yield ray
        return
    check_address(address)
    options: dict[str, Any] = {"log_to_driver": False, "logging_level": logging.WARNING}
    if address is None and not os.environ.get("RAY_ADDRESS"):
        options["include_dashboard"] = False  # only for an instance this process starts
    try:
        ray.init(address=address, **options)
    except (OSError, RuntimeError, ValueError, ray.exceptions.RayError) as e:  # Ray's start-up raises all of them
        where = "on this machine (--address auto; start one with `ray start --head`)" if address == "auto" else address
        raise ConfigError(f"cannot join the Ray cluster {where}: {e}", field="--address") from None
    try:
        yield ray
    finally:
        ray.shutdown()


def cluster_cpus() -> int:
    """The CPUs of the joined cluster, all nodes together (at least 1)."""
    ray = import_ray()
    return max(1, int(ray.cluster_resources().get("CPU", 1)))


def actor_count(workers: int | None, jobs: int) -> int:
    """How many actors: ``workers`` (``--workers``), or one per CPU of the cluster; never more than ``jobs``.

    Raises:
        ConfigError: more actors asked for than the cluster has CPUs (each holds one: the others would never start).
    """
    cpus = cluster_cpus()
    if workers is not None and workers > cpus:
        raise ConfigError(
            f"--workers {workers}: the Ray cluster has {cpus} CPUs and each worker holds one; give at most {cpus},"
            " or add nodes (ray start --address=HEAD:PORT on each)",
            field="--workers",
        )
    return max(1, min(workers or cpus, jobs))


def node_name() -> str:
    """This process's node, as an error names it: host name and IP address."""
    try:
        import ray.util

        ip = ray.util.get_node_ip_address()
    except (ImportError, RuntimeError, OSError):
        ip = "?"
    return f"{socket.gethostname()} ({ip})"


def start_actors(cls: type, count: int, *args: Any) -> list[Any]:
    """``count`` actors of ``cls`` built with ``args`` (each once, for all its jobs), one CPU each, spread over the
    nodes; an actor that dies is restarted (rebuilt from ``args``) and the job it was running retried
    :data:`TASK_RETRIES` times. ``args`` are small (a request, a spec: Ray sends them with each actor): large ones in
    Ray's object store could be gone by the time an actor is restarted."""
    ray = import_ray()
    remote = ray.remote(num_cpus=1, max_restarts=-1, max_task_retries=TASK_RETRIES, scheduling_strategy="SPREAD")(cls)
    return [remote.remote(*args) for _ in range(count)]


@dataclass(frozen=True)
class WorkerHello:
    """What an actor says once built (its ``hello()``): its node, and why it cannot work (None: it can)."""

    node: str
    problem: str | None = None

    @classmethod
    def here(cls, problem: str | None = None) -> WorkerHello:
        """This process's hello, on the node it runs on."""
        return cls(node_name(), problem)


#: How long the actors may take to be placed and built (data opened, meshes and weights read) before the command
#: stops: a cluster whose CPUs are all held by other work would otherwise leave it waiting with no word.
START_TIMEOUT_S = 600.0


def check_started(actors: list[Any]) -> list[WorkerHello]:
    """Every actor built, on its node, before any job (each answers ``hello()``): a node without bop-cender stops the
    command with one error, not with every job failed the same way. The hellos, for the caller to judge their
    problems.

    Raises:
        ConfigError: an actor could not start, or not within :data:`START_TIMEOUT_S`.
    """
    ray = import_ray()
    try:
        return ray.get([actor.hello.remote() for actor in actors], timeout=START_TIMEOUT_S)
    except ray.exceptions.GetTimeoutError:
        raise ConfigError(
            f"{len(actors)} Ray workers asked for, not all started after {START_TIMEOUT_S:.0f} s: the cluster's CPUs"
            " are held by other work (each worker needs one free), or its nodes are too slow to build the method",
            field="--workers",
        ) from None
    except ray.exceptions.RayError as e:
        raise ConfigError(
            f"a Ray worker could not start ({first_line(e)}); every node needs bop-cender installed (the same"
            " version as here), with torch: docs/cluster.md",
            field="--executor",
        ) from None


def stop_actors(actors: list[Any]) -> None:
    """End the actors (their CPUs freed for the next command of a cluster that stays up)."""
    ray = import_ray()
    for actor in actors:
        ray.kill(actor)


def as_completed(
    actors: list[Any], jobs: Iterable[Job], call: Callable[[Any, Job], Any]
) -> Iterator[tuple[Job, Any, BaseException | None]]:
    """``(job, result, None)`` or ``(job, None, error)`` per job as jobs finish: each actor runs one job at a time
    (``call(actor, job)`` submits it) and gets the next as soon as it is done, so a slow job holds back no other.

    ``error``: the Ray error of a job that raised on its actor (its cause in the message) or whose actor died on each
    of its tries; the caller decides what a failed job means."""
    ray = import_ray()
    todo = deque(jobs)
    running: dict[Any, tuple[Any, Job]] = {}

    def submit(actor: Any) -> None:
        if todo:
            job = todo.popleft()
            running[call(actor, job)] = (actor, job)

    for actor in actors:
        submit(actor)
    while running:
        (ref,), _ = ray.wait(list(running), num_returns=1)
        actor, job = running.pop(ref)
        try:
            result, error = ray.get(ref), None
        except ray.exceptions.RayError as e:
            result, error = None, e
        submit(actor)  # the actor's next job goes out before this one's result is handled
        yield job, result, error


def first_line(error: BaseException) -> str:
    """A Ray error in one line: the exception a job raised on its actor (Ray's wrapper carries it as ``cause``), else
    the Ray error's type and first line (its messages go on with tracebacks and advice)."""
    cause = getattr(error, "cause", None)
    shown = cause if isinstance(cause, BaseException) else error
    text = str(shown).strip().splitlines()
    return f"{type(shown).__name__}: {text[0] if text else ''}"
