"""Benchmark the render-and-compare cost function: poses/s of render + curvature + cost.

The workload of the renderer study (docs/performance.md): six 320x256 views on a ring 500 mm from the origin at
25 and 55 degrees elevation (fx = fy = 600, principal point at the image centre), pose candidates with
uniformly random rotations and +-15 mm translations, costs against distance maps rendered at the true
pose. Two parts made with trimesh + manifold3d: an L-bracket (80 x 50 x 56 mm, 4 holes, ~700 faces)
and a flange (~5k faces). Batch sizes 1, 4, 16, 64, 256; CPU, and CUDA where present; pyrender where
importable (an optional extra, for comparison only).

Prints a table and writes ``results/bench/render_<host>.md`` with the machine description (CPU model,
cores, torch version and threads, whether tcmalloc is preloaded, load average before and after).

    LD_PRELOAD=$(dpkg -L libtcmalloc-minimal4 | grep 'libtcmalloc_minimal.so.4$') \\
        python scripts/bench_render.py            # CPU 1 thread, and 2 chunk workers (2 cores)
"""

from __future__ import annotations

import argparse
import os
import platform
import socket
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import bench_machine
import numpy as np
import torch
import trimesh
from scipy.spatial.transform import Rotation

from bop_cender.pose.backend import backend_named
from bop_cender.pose.cost import distance_maps
from bop_cender.render.curvature import curvature
from bop_cender.render.mesh import RenderMesh, prepare_mesh
from bop_cender.render.rasterizer import render_scene
from bop_cender.synth.reference_meshes import reference_bracket
from bop_cender.synth.rigs import look_at

HEIGHT, WIDTH = 256, 320
BATCHES = (1, 4, 16, 64, 256)


@dataclass
class Row:
    part: str
    faces: int
    device: str
    batch: int
    poses_per_s: float  # median over the rounds
    best_poses_per_s: float
    ms_per_call: float  # median


def make_flange() -> trimesh.Trimesh:
    """Flange: 120 mm disc with a hub, a 32 mm bore and 8 bolt holes (about 5k faces)."""
    disc = trimesh.creation.cylinder(radius=60, height=12, sections=200)
    disc.apply_translation((0, 0, 6))
    hub = trimesh.creation.cylinder(radius=28, height=30, sections=200)
    hub.apply_translation((0, 0, 15))
    body = trimesh.boolean.union([disc, hub], engine="manifold")
    cuts = [trimesh.creation.cylinder(radius=16, height=80, sections=200)]
    for k in range(8):
        a = 2 * np.pi * k / 8
        bolt = trimesh.creation.cylinder(radius=5, height=40, sections=80)
        bolt.apply_translation((44 * np.cos(a), 44 * np.sin(a), 6))
        cuts.append(bolt)
    mesh = trimesh.boolean.difference([body, *cuts], engine="manifold")
    mesh.apply_translation(-mesh.centroid)
    return mesh


def make_rig() -> tuple[np.ndarray, np.ndarray]:
    """``T_cam_world (6, 4, 4)`` looking at the origin from 500 mm, and ``K (6, 3, 3)``."""
    poses = []
    for elevation, azimuth in [(25, 0), (25, 120), (25, 240), (55, 60), (55, 180), (55, 300)]:
        el, az = np.radians(elevation), np.radians(azimuth)
        eye = 500.0 * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        poses.append(look_at(eye, (0.0, 0.0, 0.0)))
    K = np.array([[600.0, 0.0, WIDTH / 2], [0.0, 600.0, HEIGHT / 2], [0.0, 0.0, 1.0]])
    return np.stack(poses), np.repeat(K[None], 6, axis=0)


def make_candidates(n: int, rng: np.random.Generator, T_cam_world: np.ndarray) -> np.ndarray:
    """``(n, V, 4, 4)`` random rotations, translations uniform in +-15 mm, in each camera's frame."""
    T_world_model = np.zeros((n, 4, 4))
    T_world_model[:, :3, :3] = Rotation.random(n, random_state=rng).as_matrix()
    T_world_model[:, :3, 3] = rng.uniform(-15.0, 15.0, (n, 3))
    T_world_model[:, 3, 3] = 1.0
    return np.einsum("vij,njk->nvik", T_cam_world, T_world_model)


def target_distance_maps(mesh: RenderMesh, T_cam_world: np.ndarray, K: np.ndarray) -> torch.Tensor:
    """Distance maps of the exact render at the true pose (curvature >= 1 counts as an edge)."""
    scene = render_scene([mesh], T_cam_world[:, None], K, HEIGHT, WIDTH)
    return torch.as_tensor(distance_maps((curvature(scene.normals) >= 1.0).cpu().numpy()))


def time_calls(fn: Callable[[], object], sync: Callable[[], None], seconds: float, rounds: int) -> list[float]:
    """Seconds per call in each of ``rounds`` rounds of at least ``seconds / rounds`` (after a warm-up)."""
    fn()
    sync()
    per_call = []
    for _ in range(rounds):
        calls, start = 0, time.perf_counter()
        while calls < 1 or time.perf_counter() - start < seconds / rounds:
            fn()
            calls += 1
        sync()
        per_call.append((time.perf_counter() - start) / calls)
    return per_call


def bench_torch(
    name: str, mesh: RenderMesh, device: torch.device, threads: int, workers: int, args: argparse.Namespace
) -> list[Row]:
    """poses/s of the ``auto`` backend's candidate costs for each batch size, with ``threads`` intra-op threads and
    ``workers`` chunk threads (CPU)."""
    T_cw, K = make_rig()
    dist = target_distance_maps(mesh, T_cw, K).to(device)
    mesh = mesh.to(device)
    weights = torch.ones(6, device=device)
    rng = np.random.default_rng(args.seed)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    label = f"cuda ({torch.cuda.get_device_name(device)})" if device.type == "cuda" else f"cpu {threads}x{workers}"
    torch.set_num_threads(threads)
    rows = []
    for batch in args.batches:
        T = torch.as_tensor(make_candidates(batch, rng, T_cw), dtype=torch.float32, device=device)

        def call(T: torch.Tensor = T) -> None:
            backend_named("auto").candidate_costs(mesh, T, K, HEIGHT, WIDTH, dist, weights, workers=workers)

        rows.append(_row(name, mesh.num_faces, label, batch, time_calls(call, sync, args.seconds, args.rounds)))
    return rows


def bench_pyrender(name: str, mesh: trimesh.Trimesh, args: argparse.Namespace) -> tuple[list[Row], str]:
    """pyrender, one depth render per view (normals from depth differences), if it is installed."""
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    try:
        import pyrender
    except Exception as error:  # noqa: BLE001 - any import failure means: not available here
        return [], f"pyrender not importable ({type(error).__name__}: {error}); skipped."
    T_cw, K = make_rig()
    renderer = pyrender.OffscreenRenderer(WIDTH, HEIGHT)
    scene = pyrender.Scene()
    node = scene.add(pyrender.Mesh.from_trimesh(mesh, smooth=False))
    # Explicit near/far: pyrender's default zfar (100) would clip the whole object at ~500 mm.
    camera = pyrender.IntrinsicsCamera(K[0, 0, 0], K[0, 1, 1], K[0, 0, 2], K[0, 1, 2], znear=1.0, zfar=5000.0)
    cam_node = scene.add(camera)
    flip = np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV camera axes to OpenGL's
    rng = np.random.default_rng(args.seed)
    rows = []
    check = make_candidates(1, rng, T_cw)
    scene.set_pose(node, check[0, 0])
    scene.set_pose(cam_node, flip)
    covered = int((renderer.render(scene, flags=pyrender.RenderFlags.DEPTH_ONLY) > 0).sum())
    if covered < 100:  # a timing of empty renders would be meaningless
        raise RuntimeError(f"pyrender drew only {covered} pixels of the object: camera set-up is wrong")
    for batch in args.batches:
        poses = make_candidates(batch, rng, T_cw)

        def run(poses: np.ndarray = poses) -> None:
            for b in range(poses.shape[0]):
                for v in range(poses.shape[1]):
                    scene.set_pose(node, poses[b, v])
                    scene.set_pose(cam_node, flip)
                    renderer.render(scene, flags=pyrender.RenderFlags.DEPTH_ONLY)

        rows.append(
            _row(name, len(mesh.faces), "pyrender", batch, time_calls(run, lambda: None, args.seconds, args.rounds))
        )
    renderer.delete()
    return rows, "pyrender: depth-only renders, 6 per pose (no curvature or cost): an upper bound on its speed."


def _row(part: str, faces: int, device: str, batch: int, per_call: list[float]) -> Row:
    median, best = float(np.median(per_call)), min(per_call)
    row = Row(part, faces, device, batch, batch / median, batch / best, median * 1e3)
    print(
        f"{part:8s} {faces:5d} faces  {device:12s} B={batch:4d}  {row.poses_per_s:8.1f} poses/s "
        f"(best {row.best_poses_per_s:.1f})  {row.ms_per_call:8.2f} ms/call",
        flush=True,
    )
    return row


def machine_slug() -> str:
    """``amd-epyc-2cores`` (and the GPU, where there is one): the results file's name."""
    return bench_machine.machine_slug(torch.cuda.get_device_name(0) if torch.cuda.is_available() else None)


def machine_description() -> list[str]:
    model = bench_machine.cpu_model()
    maps = Path("/proc/self/maps")
    tcmalloc = maps.exists() and "tcmalloc" in maps.read_text()
    lines = [
        f"- host: {socket.gethostname()} ({platform.platform()})",
        f"- CPU: {model}, {os.cpu_count()} logical cores, {len(os.sched_getaffinity(0))} usable",
        f"- torch {torch.__version__}, CUDA: "
        + (torch.cuda.get_device_name(0) if torch.cuda.is_available() else "none"),
        f"- tcmalloc preloaded: {'yes' if tcmalloc else 'no'} (LD_PRELOAD={os.environ.get('LD_PRELOAD', '')!r}), "
        f"OMP_WAIT_POLICY={os.environ.get('OMP_WAIT_POLICY', '(unset)')}",
    ]
    return lines


def write_report(path: Path, rows: list[Row], notes: list[str], machine: list[str], loads: tuple, command: str) -> None:
    out = ["# Cost-function benchmark (render + curvature + cost, six 320x256 views)", ""]
    out += [f"Command: `{command}`", ""]
    out += machine
    out += [f"- load average (1, 5, 15 min) before: {loads[0]}, after: {loads[1]}", ""]
    out += [
        "| part | faces | device | batch | poses/s (median) | poses/s (best) | ms per call (median) |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    out += [
        f"| {r.part} | {r.faces} | {r.device} | {r.batch} | {r.poses_per_s:.1f} | {r.best_poses_per_s:.1f} "
        f"| {r.ms_per_call:.2f} |"
        for r in rows
    ]
    out += [""] + [f"- {n}" for n in notes]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(out) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--cpu",
        nargs="+",
        default=["1x1", "1x2"],
        help="CPU configurations THREADSxWORKERS: torch intra-op threads x chunk worker threads",
    )
    parser.add_argument("--batches", type=int, nargs="+", default=list(BATCHES))
    parser.add_argument("--seconds", type=float, default=3.0, help="timing per measurement (all rounds)")
    parser.add_argument("--rounds", type=int, default=5, help="rounds per measurement (median and best)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--parts", nargs="+", default=["bracket", "flange"], choices=["bracket", "flange"])
    parser.add_argument("--no-cuda", action="store_true")
    parser.add_argument("--out", type=Path, default=None, help="report path (default results/bench/...)")
    args = parser.parse_args()
    configs = [tuple(int(x) for x in c.split("x")) for c in args.cpu]
    load_before = tuple(round(x, 2) for x in os.getloadavg())
    parts = {"bracket": reference_bracket, "flange": make_flange}
    rows: list[Row] = []
    notes: list[str] = []
    for name in args.parts:
        tm = parts[name]()
        mesh = prepare_mesh(tm)
        for threads, workers in configs:
            rows += bench_torch(name, mesh, torch.device("cpu"), threads, workers, args)
        if torch.cuda.is_available() and not args.no_cuda:
            rows += bench_torch(name, mesh, torch.device("cuda"), 1, 1, args)
        py_rows, note = bench_pyrender(name, tm, args)
        rows += py_rows
        if note not in notes:
            notes.append(note)
    if not torch.cuda.is_available():
        notes.append("CUDA: not available on this machine; not measured.")
    load_after = tuple(round(x, 2) for x in os.getloadavg())
    path = args.out or Path(__file__).resolve().parents[1] / "results" / "bench" / f"render_{machine_slug()}.md"
    notes.append(
        "cpu TxW: T torch intra-op threads, W threads rendering independent chunks side by side "
        "(`Backend.candidate_costs(..., workers=W)`)."
    )
    command = " ".join(["python", "scripts/bench_render.py", *sys.argv[1:]])
    if os.environ.get("LD_PRELOAD"):
        command = f"LD_PRELOAD={os.environ['LD_PRELOAD']} {command}"
    write_report(path, rows, notes, machine_description(), (load_before, load_after), command)
    print(f"load average before {load_before}, after {load_after}; wrote {path}")


if __name__ == "__main__":
    main()
