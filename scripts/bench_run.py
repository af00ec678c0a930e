"""Benchmark the method: cost calls/s (batches of 2,000 and of 1) and seconds per scene by stage.

1. Cost calls per second, one call = one pose over six 320x256 views (render + curvature + cost), the
   workload of ``scripts/bench_render.py`` (the reference L-bracket, ~700 faces): a batch of 2,000 (the
   candidates of one object) and a batch of 1 (one Nelder-Mead step of the scipy refiner). CPU, and
   CUDA where present.
   The same for the edge-point proxy that ranks the candidates and drives most of Nelder-Mead
   (``search_cost=edges``, :mod:`bop_cender.pose.edge_cost`), and the scene polish's windowed scene cost
   against the full scene cost (:mod:`bop_cender.pose.scene_polish`).
   With ``--profile``: where one cost call's time goes (torch.profiler, batches of 1 and 8): wall time, the
   operators it runs, the CUDA kernels it launches and the calls that wait for the device (``nonzero``,
   ``item``, copies, synchronisations): why a small batch on a GPU is bound by the host; and one edge-proxy call
   of 3 poses in each of its layouts (the kernel, the CPU's default: no torch operator; compacted torch; dense
   torch, CUDA's fallback: no synchronising call; the CUDA kernel, CUDA's default where numba's CUDA target works:
   one launch).
2. Seconds per scene end to end, split by stage (heatmaps, centers, poses), for DIMO-layout scenes
   with oracle heatmaps and the default config (``--data-root`` a DIMO-layout dataset; default the
   embedded demo), one process as ``bop-cender run`` runs it (one torch thread, the render search's
   candidate chunks on 2 threads; ``--torch-threads`` and ``--chunk-threads`` to compare), on the last of
   ``--devices`` (stage 3 too: ``run`` itself keeps stage 3 on the CPU unless ``--pose-device`` says otherwise).

Prints a table and writes ``results/bench/run_<machine>.md``:

    python scripts/bench_run.py --data-root DATA --split sim --scenes 2 [--devices cpu|cuda|cpu,cuda] [--profile]
"""

from __future__ import annotations

import argparse
import itertools
import os
import sys
import time
from functools import partial
from pathlib import Path

import bench_machine
import bench_render
import numpy as np
import torch

from bop_cender.pose.backend import Backend, TorchBackend, backend_named
from bop_cender.pose.edge_model import edge_model_of
from bop_cender.render.mesh import prepare_mesh
from bop_cender.synth.reference_meshes import reference_bracket


def _workload(device: torch.device, batch: int):
    """The reference bracket, ``batch`` candidate poses over the six views, intrinsics, distance maps, weights."""
    mesh = prepare_mesh(reference_bracket(), device=device)
    T_cw, K = bench_render.make_rig()
    dist = bench_render.target_distance_maps(mesh, T_cw, K).to(device)
    rng = np.random.default_rng(0)
    T = torch.as_tensor(bench_render.make_candidates(batch, rng, T_cw), dtype=torch.float32, device=device)
    Ks = torch.as_tensor(K, dtype=torch.float32, device=device)
    w = torch.full((len(K),), 1.0 / len(K), device=device)
    return mesh, T, Ks, dist, w


def _calls_per_second(call, device: torch.device, batch: int, seconds: float) -> tuple[float, float]:
    """Median poses/s and ms per call of ``call()`` (one warm-up call, then at least 3 within ``seconds``)."""
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    call()
    sync()
    times = []
    end = time.perf_counter() + seconds
    while time.perf_counter() < end or len(times) < 3:
        t = time.perf_counter()
        call()
        sync()
        times.append(time.perf_counter() - t)
    per_call = float(np.median(times))
    return batch / per_call, per_call * 1000


def cost_calls_per_second(
    device: torch.device, batch: int, seconds: float, workers: int = 1, backend: str = "auto"
) -> tuple[float, float]:
    """Median calls/s and ms per cost call of ``batch`` poses over six views (``workers`` chunk threads of the torch
    atlases; ``backend``: the backend's name, :mod:`bop_cender.pose.backend`: ``numba`` on the CPU the compiled loop,
    :mod:`bop_cender.pose.cost_kernel`; ``torch`` the torch atlases; ``auto`` the device's default)."""
    mesh, T, Ks, dist, w = _workload(device, batch)
    costs = backend_named(backend)

    def call() -> None:
        costs.candidate_costs(mesh, T, Ks, bench_render.HEIGHT, bench_render.WIDTH, dist, w, workers=workers)

    return _calls_per_second(call, device, batch, seconds)


def _cuda_default_label() -> str:
    """What the ``auto`` backend's candidate costs run on CUDA here: the kernel, or the torch atlases and why."""
    from bop_cender.render.cuda_loops import cuda_unavailable_reason

    reason = cuda_unavailable_reason()
    return "CUDA kernel (numba, one launch)" if reason is None else f"torch atlases ({reason})"


def edge_calls_per_second(
    device: torch.device, batch: int, seconds: float, max_segments: int | None, layout: str | None = None
) -> tuple[float, float]:
    """Median calls/s and ms per call of the edge-point proxy (:mod:`bop_cender.pose.edge_cost`) on the same
    workload as :func:`cost_calls_per_second`; ``max_segments``: the sparse model of the candidates' ranking;
    ``layout``: its layout (:func:`_edge_backend`; None: the device's default, the kernel on the CPU, the CUDA kernel
    or dense on CUDA)."""
    mesh, T, Ks, dist, w = _workload(device, batch)
    model = _edge_model(mesh, max_segments)
    backend = _edge_backend(layout)
    return _calls_per_second(lambda: backend.edge_costs(model, T, Ks, dist, w), device, batch, seconds)


def _edge_backend(layout: str | None) -> Backend:
    """The backend that runs the edge proxy in ``layout`` (the rows' label): ``kernel`` (the CPU) and ``cuda`` (CUDA)
    the ``numba`` backend, ``compacted`` and ``dense`` the ``torch`` backend's two layouts, None the ``auto`` backend."""
    if layout in ("compacted", "dense"):
        return TorchBackend(dense_edges=layout == "dense")
    return backend_named({None: "auto", "kernel": "numba", "cuda": "numba"}[layout])


def _cuda_edge_kernel_unavailable() -> str | None:
    """Why the CUDA edge kernel cannot run here (None: it can)."""
    from bop_cender.pose.cuda_edge_kernel import GUARD

    return GUARD.unavailable()


def _edge_model(mesh, max_segments: int | None):
    model = edge_model_of(mesh)
    return model if max_segments is None else model.sparse(max_segments)


#: Profiler events that make the host wait for the device (sizes read back, copies, explicit synchronisation).
#: The one ``cudaDeviceSynchronize`` that :func:`_profile` itself makes, to collect the kernels, is not counted.
_SYNC_EVENTS = ("aten::nonzero", "aten::item", "aten::_local_scalar_dense", "aten::_unique2", "aten::masked_select",
                "cudaStreamSynchronize", "cudaDeviceSynchronize", "cudaMemcpyAsync")  # fmt: skip


def cost_call_profile(
    device: torch.device, batches: tuple[int, ...] = (1, 8), backend: str = "auto"
) -> list[tuple[str, float, int, int, int]]:
    """One cost call of each batch size profiled (after 3 warm-ups): ``(batch and path, wall ms of an unprofiled call,
    aten operators, CUDA kernel launches, synchronising calls)`` (launches and syncs 0 on the CPU but ``nonzero`` and
    ``item``, which only synchronise on a GPU); ``backend`` the backend's name (``auto``: the device's default, the
    compiled loop on the CPU, the kernel on CUDA; ``torch``: the torch atlases)."""
    rows = []
    path = "torch atlases" if backend == "torch" else "default"
    for batch in batches:
        mesh, T, Ks, dist, w = _workload(device, batch)
        call = partial(backend_named(backend).candidate_costs, mesh, T, Ks, bench_render.HEIGHT, bench_render.WIDTH,
                       dist, w)  # fmt: skip
        rows.append((f"{batch}, {path}", *_profile(call, device)))
        print(f"profile {device.type} batch {batch} ({path}): " + _profile_line(rows[-1][1:]), flush=True)
    return rows


def edge_call_profile(device: torch.device, batch: int = 3) -> list[tuple[str, float, int, int, int]]:
    """:func:`cost_call_profile` of one edge-proxy call (full model; ``batch`` poses: a Nelder-Mead step) in each
    layout of the device: ``(layout, ms, operators, launches, synchronising calls)``. The dense layout (CUDA's
    fallback) makes no ``nonzero`` and reads no size from a tensor, so on a GPU nothing waits before the result is
    read; the kernel (the CPU's default) runs no torch operator at all."""
    mesh, T, Ks, dist, w = _workload(device, batch)
    model = _edge_model(mesh, None)
    rows = []
    own = ("kernel",) if device.type == "cpu" else ("cuda",) if _cuda_edge_kernel_unavailable() is None else ()
    for layout in ("compacted", "dense", *own):
        rows.append((layout, *_profile(partial(_edge_backend(layout).edge_costs, model, T, Ks, dist, w), device)))
        print(f"profile edge proxy {device.type} batch {batch} {layout}: " + _profile_line(rows[-1][1:]), flush=True)
    return rows


def _profile(call, device: torch.device) -> tuple[float, int, int, int]:
    """``(wall ms of an unprofiled call, aten operators, CUDA kernel launches, synchronising calls)`` of ``call()``
    after 3 warm-ups (the synchronisation after the call, which collects its kernels, not counted)."""
    from torch.profiler import ProfilerActivity, profile

    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.type == "cuda" else [])
    for _ in range(3):
        call()
    sync()
    with profile(activities=activities) as prof:
        call()
        sync()
    events = prof.key_averages()
    ops = sum(e.count for e in events if e.key.startswith("aten::"))
    launches = sum(e.count for e in events if e.key == "cudaLaunchKernel")
    syncs = sum(e.count for e in events if e.key in _SYNC_EVENTS) - (1 if device.type == "cuda" else 0)
    t = time.perf_counter()
    call()
    sync()
    return (time.perf_counter() - t) * 1000, ops, launches, syncs


def _profile_line(row: tuple[float, int, int, int]) -> str:
    ms, ops, launches, syncs = row
    return f"{ms:.2f} ms, {ops} aten ops, {launches} kernel launches, {syncs} synchronising calls"


def scene_timings(
    data_root: str | None,
    split: str,
    n_scenes: int,
    device: str,
    chunk_threads: int = 2,
    torch_threads: int = 1,
    settings: tuple[str, ...] = (),
    pose_device: str | None = None,
    loop_threads: int | None = None,
) -> list[dict]:
    """Seconds per scene by stage: heatmaps (the oracle) on ``device``, stage 3 on ``pose_device`` (default the
    same; ``run`` keeps stage 3 on the CPU, its compiled loops on torch's thread count, or ``loop_threads`` as
    ``run --threads`` gives them)."""
    from bop_cender.data.registry import DatasetRequest
    from bop_cender.datasets import open_with_demo
    from bop_cender.meshes import MeshCache
    from bop_cender.method import CenDerNet, CenDerNetConfig
    from bop_cender.net.oracle import OraclePredictor
    from bop_cender.render.numba_loops import compiled_threads

    ds = open_with_demo(DatasetRequest("dimo", data_root, split))  # no data root: the embedded demo, silently
    config = CenDerNetConfig.for_dataset("dimo").with_settings(settings)
    meshes = MeshCache(ds.models)
    oracle = OraclePredictor(ds.models, meshes, config.targets, device=device)
    # as a one-process `bop-cender run` does: one torch thread, the render search's chunks on the cores
    # (``--torch-threads`` to compare)
    # stage 3 on the timed device too (``run`` keeps it on the CPU unless --pose-device says otherwise)
    method = CenDerNet(ds.models, config, oracle, meshes, cost_threads=chunk_threads, pose_device=pose_device or device)
    torch.set_num_threads(torch_threads)
    with compiled_threads(loop_threads or torch_threads):
        if max(torch_threads, loop_threads or 1) > 1 and ds.scene_keys:  # threaded loops compile on first use
            method.estimate(ds.scene(ds.scene_keys[0]))
        out = []
        for key in ds.scene_keys[:n_scenes]:
            scene = ds.scene(key)
            t = time.perf_counter()
            est = method.estimate(scene)
            wall = time.perf_counter() - t
            n_parts = sum(ds.models[g.obj_id].is_target for g in scene.gt)
            out.append({"scene": key, "views": len(scene.views), "parts": n_parts, "objects": len(est.objects),
                        "wall": wall, **est.timings})  # fmt: skip
            print(f"scene {key}: {wall:.1f} s " + ", ".join(f"{k} {v:.1f}" for k, v in est.timings.items()), flush=True)
    return out


def scene_polish_costs(
    data_root: str | None, split: str, seconds: float, device: torch.device | None = None
) -> list[tuple[str, int, float, float]]:
    """The scene polish's cost against the full scene cost it stands for, on the first scene of the split (GT
    poses, oracle maps; on the CPU with one torch thread, or on ``device``): ms per pose of the full scene cost
    (all parts rendered in every full frame) and of the windowed cost of the first part
    (:mod:`bop_cender.pose.scene_polish`) for batches of 1 (a Nelder-Mead step) and 7 (its first simplex).
    Returns ``(what, batch, poses/s, ms per call)``."""
    from bop_cender.data.registry import DatasetRequest
    from bop_cender.datasets import open_with_demo
    from bop_cender.meshes import MeshCache
    from bop_cender.method import CenDerNetConfig
    from bop_cender.net.oracle import OraclePredictor
    from bop_cender.pose.cost import distance_maps
    from bop_cender.pose.scene_polish import scene_window
    from bop_cender.render.rasterizer import render_scene

    device = torch.device("cpu") if device is None else device
    ds = open_with_demo(DatasetRequest("dimo", data_root, split))
    config = CenDerNetConfig.for_dataset("dimo")
    meshes = MeshCache(ds.models)
    scene = ds.scene(ds.scene_keys[0])
    maps = OraclePredictor(ds.models, meshes, config.targets).predict(scene)
    edges = (maps.curvature > config.poses.t_b).to(device)
    dist = torch.as_tensor(distance_maps(edges.cpu().numpy())).to(device)
    threshold = config.poses.t_b * config.targets.curvature_scale
    parts = [g for g in scene.gt if ds.models[g.obj_id].is_target]
    Ks = np.stack([v.K for v in scene.views])
    T_cw = np.stack([v.T_cam_world for v in scene.views])
    T_cm = torch.as_tensor(
        np.einsum("vij,mjk->vmik", T_cw, np.stack([g.T_world_model for g in parts])), dtype=torch.float32,
        device=device,
    )  # fmt: skip
    part_meshes = [meshes(g.obj_id).to(device) for g in parts]
    others = [(mesh, g.T_world_model) for mesh, g in zip(part_meshes[1:], parts[1:], strict=True)]
    window = scene_window(part_meshes[0], parts[0].T_world_model, others, Ks, T_cw, edges, dist, threshold,
                          config.poses.scene_polish.margin_px)  # fmt: skip
    threads = torch.get_num_threads()
    if device.type == "cpu":
        torch.set_num_threads(1)
    K = torch.as_tensor(Ks, dtype=torch.float32, device=device)
    auto, torch_backend = backend_named("auto"), backend_named("torch")
    rows = [(f"full scene cost ({len(parts)} parts, {len(Ks)} views)", 1,
             *_calls_per_second(lambda: auto.scene_cost(part_meshes, T_cm, K, edges, dist, threshold), device, 1,
                                seconds))]  # fmt: skip
    if device.type == "cuda":  # the kernel (the default) against the torch steps it replaced
        rows.append((f"full scene cost ({len(parts)} parts, {len(Ks)} views), torch steps (no kernel)", 1,
                     *_calls_per_second(lambda: torch_backend.scene_cost(part_meshes, T_cm, K, edges, dist, threshold),
                                        device, 1, seconds)))  # fmt: skip
    for batch in (1, 7):
        T = np.repeat(parts[0].T_world_model[None], batch, 0)
        rows.append((f"windowed cost, windows {window.size[0]}x{window.size[1]}", batch,
                     *_calls_per_second(lambda T=T: auto.window_costs(window, T), device, batch, seconds)))  # fmt: skip
    # the same call as torch operators (the torch backend: on CUDA the path before the CUDA window kernel, and still
    # the fallback where numba's CUDA target is missing)
    T = parts[0].T_world_model[None]
    how = "torch backend (torch render and steps)" if device.type == "cpu" else "torch steps (no kernel)"
    rows.append((f"windowed cost, windows {window.size[0]}x{window.size[1]}, {how}", 1,
                 *_calls_per_second(lambda: torch_backend.window_costs(window, T), device, 1, seconds)))  # fmt: skip
    if device.type == "cpu":
        # the renders alone, torch pipeline against the compiled loop (render_scene's CPU default; the same bits)
        h, w = window.size
        T_win = torch.as_tensor(np.einsum("vij,jk->vik", window.T_cam_world, parts[0].T_world_model)[:, None],
                                dtype=torch.float32)  # fmt: skip
        H, W = scene.views[0].height, scene.views[0].width
        renders = {f"render alone, the part's {len(Ks)} windows {h}x{w}": lambda b: render_scene(
                       [window.mesh], T_win, window.K, h, w, backend=b),
                   f"render alone, {len(Ks)} full frames of {len(parts)} parts": lambda b: render_scene(
                       part_meshes, T_cm, K, H, W, backend=b)}  # fmt: skip
        for what, render in renders.items():
            for backend, how in ((torch_backend, "torch pipeline"), (backend_named("numba"), "compiled")):
                rows.append((f"{what}, {how}", 1,
                             *_calls_per_second(lambda r=render, b=backend: r(b), device, 1, seconds)))  # fmt: skip
    torch.set_num_threads(threads)
    for what, batch, calls, ms in rows:
        print(f"scene polish ({device.type}): {what}, batch {batch}: {calls:,.0f} poses/s ({ms:.2f} ms per call)",
              flush=True)  # fmt: skip
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data-root", default=None, help="DIMO-layout dataset (default: the embedded demo)")
    ap.add_argument("--split", default="sim")
    ap.add_argument("--scenes", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=5.0, help="timing budget per cost measurement")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument(
        "--chunk-threads", type=int, default=2, help="the render search's chunk threads in the scene timing"
    )
    ap.add_argument("--torch-threads", type=int, default=1, help="torch threads in the scene timing (run: 1)")
    ap.add_argument("--devices", default=None,
                    help="comma-separated devices to time (default: cpu, and cuda where present); the scene timing "
                         "and the scene polish run on the last one")  # fmt: skip
    ap.add_argument("--profile", action="store_true",
                    help="also profile one cost call of 1 and of 8 poses, and an edge-proxy call in each layout, on each"
                         " device (torch.profiler)")  # fmt: skip
    ap.add_argument("--pose-device", choices=("cpu", "cuda"), default=None,
                    help="stage 3's device in the scene timing (default: the last of --devices); `run` keeps stage 3 on"
                         " the CPU: --devices cuda --pose-device cpu --torch-threads N times a GPU host as run uses it")  # fmt: skip
    ap.add_argument("--loop-threads", type=int, default=None,
                    help="threads of the compiled loops in the scene timing (default: --torch-threads), as run --threads")  # fmt: skip
    ap.add_argument("--scenes-only", action="store_true",
                    help="time the scenes alone (no cost calls, edge proxy or scene polish)")  # fmt: skip
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE",
                    help="a method setting for the scene timing, as run's --set (poses.search_cost=render: the paper's search)")  # fmt: skip
    args = ap.parse_args()
    load_before = os.getloadavg()
    if args.devices is None:
        devices = [torch.device("cpu")] + ([torch.device("cuda")] if torch.cuda.is_available() else [])
    else:
        names = [d.strip() for d in args.devices.split(",") if d.strip()]
        if not names or any(n not in ("cpu", "cuda") for n in names):
            ap.error(f"--devices {args.devices!r}: expected cpu and/or cuda")
        devices = [torch.device(n) for n in names]
        if any(d.type == "cuda" for d in devices) and not torch.cuda.is_available():
            ap.error("--devices names cuda but no CUDA device is present")
    cost_rows, edge_rows = [], []
    threads = torch.get_num_threads()
    cores = bench_machine.usable_cores()
    for device in [] if args.scenes_only else devices:
        # (batch, torch threads, chunk threads, backend): on the CPU the compiled loop (numba, the default) with one
        # thread (as `run` calls it) and with all, then the torch atlases for reference
        setups = (
            [(2000, 1, 1, "numba"), (2000, threads, 1, "numba"), (2000, threads, 1, "torch"), (2000, 1, cores, "torch"),
             (1, 1, 1, "numba"), (1, threads, 1, "torch")]
            if device.type == "cpu"
            else [(2000, threads, 1, "auto"), (1, threads, 1, "auto"), (2000, threads, 1, "torch"),
                  (1, threads, 1, "torch")]
        )  # fmt: skip
        for batch, n_threads, workers, backend in setups:
            torch.set_num_threads(n_threads)
            calls, ms = cost_calls_per_second(device, batch, args.seconds, workers, backend)
            how = (
                f"compiled, {n_threads} thread(s)"
                if backend == "numba"
                else _cuda_default_label()
                if backend == "auto"
                else f"torch atlases, {n_threads} torch thread(s), {workers} chunk thread(s)"
            )
            cost_rows.append((device.type, batch, how, calls, ms))
            print(f"cost {device.type} batch {batch} ({how}): {calls:,.0f} calls/s ({ms:.2f} ms per call)", flush=True)
    torch.set_num_threads(threads)
    for device in [] if args.scenes_only else devices:
        # each device's default layout, then the compacted torch one for reference; on the CPU the kernel with one
        # thread too (as `run` calls it: one torch thread per process)
        layouts = [("dense", threads), ("compacted", threads)]
        if device.type == "cuda":
            reason = _cuda_edge_kernel_unavailable()
            if reason is None:  # the CUDA kernel, the default where numba's CUDA target works
                layouts.insert(0, ("cuda", threads))
            else:
                print(f"edge proxy: no CUDA kernel rows ({reason})", flush=True)
        if device.type == "cpu":
            layouts = (
                [("kernel", 1), ("kernel", threads), ("compacted", threads)]
                if threads > 1
                else [("kernel", 1), ("compacted", 1)]
            )
        for (batch, segments, label), (layout, n_threads) in itertools.product(
            ((2000, 600, "candidates (sparse, 600 segments)"), (2000, None, "full model"),
             (3, None, "full model (a Nelder-Mead step of 3 starts)")), layouts):  # fmt: skip
            torch.set_num_threads(n_threads)
            calls, ms = edge_calls_per_second(device, batch, args.seconds, segments, layout)
            how = f"{layout}, {n_threads} thread(s)"
            edge_rows.append((device.type, batch, label, how, calls, ms))
            print(
                f"edge proxy {device.type} batch {batch} {label} ({how}): {calls:,.0f} calls/s ({ms:.2f} ms per call)",
                flush=True,
            )
    torch.set_num_threads(threads)
    profiled = args.profile and not args.scenes_only
    profile_rows = (
        [(d.type, *row) for d in devices for b in ("auto", "torch")[: 1 + (d.type == "cuda")] for row in
         cost_call_profile(d, backend=b)]
        if profiled
        else []
    )  # fmt: skip
    edge_profile_rows = [(d.type, *row) for d in devices for row in edge_call_profile(d)] if profiled else []
    polish_rows = [] if args.scenes_only else scene_polish_costs(args.data_root, args.split, args.seconds, devices[-1])
    pose_device = args.pose_device or devices[-1].type
    scenes = scene_timings(
        args.data_root,
        args.split,
        args.scenes,
        devices[-1].type,
        args.chunk_threads,
        args.torch_threads,
        tuple(args.set),
        pose_device,
        args.loop_threads,
    )
    load_after = os.getloadavg()
    slug = bench_machine.machine_slug(torch.cuda.get_device_name(0) if torch.cuda.is_available() else None)
    name = f"run_{slug}.md"
    if args.scenes_only:  # beside the full benchmark's file, not over it
        loops = args.loop_threads or args.torch_threads
        name = f"run_{slug}_scenes_heatmaps-{devices[-1].type}_poses-{pose_device}-{args.torch_threads}threads-{loops}loops.md"
    path = args.out or Path(__file__).resolve().parents[1] / "results" / "bench" / name
    lines = ["# Method benchmark (`scripts/bench_run.py`)", "", f"Command: `python scripts/{Path(__file__).name} "
             + " ".join(sys.argv[1:]) + "`", ""]  # fmt: skip
    lines += bench_render.machine_description()
    lines += [f"- load average before / after: {load_before[0]:.2f} / {load_after[0]:.2f}"]
    if cost_rows:
        lines += ["", "## Cost calls per second (one call = one pose over six 320x256 views, reference bracket)", "",
                  "| device | batch | threads | calls/s | ms per call |", "|---|---:|---|---:|---:|"]  # fmt: skip
        lines += [f"| {d} | {b} | {h} | {c:,.0f} | {m:.2f} |" for d, b, h, c, m in cost_rows]
    if edge_rows:
        lines += ["", "## Edge-point proxy calls per second (the search cost of `search_cost=edges`, same workload)",
                  "", "| device | batch | model | layout, threads | calls/s | ms per call |",
                  "|---|---:|---|---|---:|---:|"]  # fmt: skip
        lines += [f"| {d} | {b} | {h} | {lay} | {c:,.0f} | {m:.2f} |" for d, b, h, lay, c, m in edge_rows]
    if profile_rows:
        lines += ["", "## One cost call profiled (`--profile`: torch.profiler, one call after 3 warm-ups)", "",
                  "| device | batch, path | ms per call | aten operators | CUDA kernel launches | synchronising calls |",
                  "|---|---|---:|---:|---:|---:|"]  # fmt: skip
        lines += [f"| {d} | {b} | {ms:.2f} | {o} | {k} | {s} |" for d, b, ms, o, k, s in profile_rows]
        lines += ["", "One edge-proxy call profiled (full model, 3 poses: a Nelder-Mead step), in each layout:", "",
                  "| device | layout | ms per call | aten operators | CUDA kernel launches | synchronising calls |",
                  "|---|---|---:|---:|---:|---:|"]  # fmt: skip
        lines += [f"| {d} | {lay} | {ms:.2f} | {o} | {k} | {s} |" for d, lay, ms, o, k, s in edge_profile_rows]
    if polish_rows:
        lines += ["", f"## Scene polish: the windowed scene cost against the full one (first scene, GT poses, {devices[-1].type}"
                  + (", 1 thread)" if devices[-1].type == "cpu" else ")"),
                  "", "| cost | batch | poses/s | ms per call |", "|---|---:|---:|---:|"]  # fmt: skip
        lines += [f"| {w} | {b} | {c:,.0f} | {m:.2f} |" for w, b, c, m in polish_rows]
    where = devices[-1].type if pose_device == devices[-1].type else f"heatmaps {devices[-1].type}, poses {pose_device}"
    lines += ["", f"## Seconds per scene (DIMO layout, split {args.split}, oracle heatmaps, default config, {where},"
              f" {args.torch_threads} torch thread(s), compiled loops on {args.loop_threads or args.torch_threads})", "",
              "| scene | views | parts | estimated | wall s | heatmaps s | centers s | poses s |",
              "|---|---:|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    lines += [f"| {s['scene']} | {s['views']} | {s['parts']} | {s['objects']} | {s['wall']:.1f} | {s['heatmaps']:.2f}"
              f" | {s['centers']:.2f} | {s['poses']:.1f} |" for s in scenes]  # fmt: skip
    if scenes:
        lines += ["", f"Median wall time per scene: {np.median([s['wall'] for s in scenes]):.1f} s"]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
