"""Benchmark stage 1: training images/s and inference ms per view of the U-Net variants, CPU and CUDA.

The paper's variants (``dimo`` 320x256, ``tless`` 720x540) and ours for 2 CPU cores (``dimo-lean``,
``dimo-context``, the lean one with dilated context blocks and the shipped DIMO model, ``dimo-refine``, that one
with a full-resolution curvature refinement, ``dimo-centers``, that one with a centre-only branch, ``dimo-votes``, that
one with centre votes, ``tless-lean``, ``tless-factored`` and ``tless-votes``, that one with centre votes, the shipped
T-LESS model; the votes' splatting is in the inference time, their loss not in training's), on random images of each variant's size (whole images; T-LESS
training also on the 270x360 crops that we train it on). Inference: batch of one view and the batch of a
7-view DIMO scene (5 views T-LESS), median of the timed repeats after a warm-up, probabilities out as the
predictor runs it; training: BCE on both heads' outputs, backward and an Adam step on batches of 8 (T-LESS 4),
as training's losses take them (a factored head's raw channels). CUDA with bf16 autocast, as
``bop-cender train`` trains there. Goal: the shipped DIMO model at most 150 ms per 320x256 view on 2 CPU cores.

Prints a table and writes ``results/bench/net_<machine>.md``:

    python scripts/bench_net.py [--repeats 5] [--devices cpu,cuda]

It also times the heads' post-processing at 720x540 (a T-LESS view): the vote map (:func:`~bop_cender.net.votes.vote_map`)
of a vote field where a given share of the pixels votes (7 % on a T-LESS test view with the shipped network), and a
factored head's probabilities over 30 classes, all of them or restricted to a scene's 5 (``run`` restricts them
to the objects its BOP targets name, and its maps hold those 5 channels only).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import bench_machine
import torch
import torch.nn.functional as F
from torch.utils.flop_counter import FlopCounterMode

from bop_cender.data.bop_io import write_text_atomic
from bop_cender.net.unet import UNet, UNetSpec, center_probabilities, count_parameters
from bop_cender.net.votes import vote_map

VARIANTS = [  # name, spec, (H, W), views per scene, training batch, training crop
    ("dimo (paper)", UNetSpec.dimo(), (256, 320), 7, 8, None),
    ("dimo-lean", UNetSpec.dimo_lean(), (256, 320), 7, 8, None),
    ("dimo-context (shipped)", UNetSpec.dimo_context(), (256, 320), 7, 8, None),
    ("dimo-refine", UNetSpec.dimo_refine(), (256, 320), 7, 8, None),
    ("dimo-centers", UNetSpec.dimo_centers(), (256, 320), 7, 8, None),
    ("dimo-votes", UNetSpec.dimo_votes(), (256, 320), 7, 8, None),
    ("tless (paper)", UNetSpec.tless(), (540, 720), 5, 4, (270, 360)),
    ("tless-lean", UNetSpec.tless_lean(), (540, 720), 5, 4, (270, 360)),
    ("tless-factored", UNetSpec.tless_factored(), (540, 720), 5, 4, (270, 360)),
    ("tless-refine", UNetSpec.tless_refine(), (540, 720), 5, 4, (270, 360)),
    ("tless-votes (shipped)", UNetSpec.tless_votes(), (540, 720), 5, 4, (270, 360)),
]


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _timed(fn, device: torch.device, repeats: int) -> float:
    fn()  # warm-up
    _sync(device)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        _sync(device)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def bench_variant(spec: UNetSpec, size, views: int, batch: int, crop, device: torch.device, repeats: int) -> dict:
    torch.manual_seed(0)
    model = UNet(spec).to(device)
    amp = dict(device_type="cuda", dtype=torch.bfloat16, enabled=device.type == "cuda")
    model.eval()
    one = torch.rand(1, 3, *size, device=device)
    scene = torch.rand(views, 3, *size, device=device)

    def infer(x):  # as the predictor runs it: probabilities out
        with torch.no_grad(), torch.autocast(**amp):
            model.probabilities(x)

    ms_one = 1000 * _timed(lambda: infer(one), device, repeats)
    ms_scene = 1000 * _timed(lambda: infer(scene), device, repeats) / views
    model.train()
    optimiser = torch.optim.Adam(model.parameters(), lr=3e-4)
    train_size = crop or size
    x = torch.rand(batch, 3, *train_size, device=device)
    c_t = torch.rand(batch, spec.center_channels + int(spec.factored_centers), *train_size, device=device)
    k_t = torch.rand(batch, *train_size, device=device)

    def step():
        with torch.autocast(**amp):
            c, k = model.forward_raw(x)  # the heads' outputs, as training's losses take them
        loss = F.binary_cross_entropy_with_logits(c.float(), c_t) + F.binary_cross_entropy_with_logits(k.float(), k_t)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()

    images_per_s = batch / _timed(step, device, max(2, repeats // 2))
    with FlopCounterMode(display=False) as counter, torch.no_grad():
        model.eval()(one)
    return {
        "params": count_parameters(model),
        "gmac": counter.get_total_flops() / 2e9,
        "ms_one": ms_one,
        "ms_scene": ms_scene,
        "train_images_per_s": images_per_s,
        "train_size": train_size,
    }


def bench_post_processing(device: torch.device, repeats: int, voting_share: float = 0.07) -> dict[str, float]:
    """ms per 720x540 view of the heads' post-processing, on a batch of 5 views (a T-LESS group)."""
    gen = torch.Generator().manual_seed(0)
    B, H, W = 5, 540, 720
    votes = torch.randn(B, 4, H, W, generator=gen)
    votes[:, 0] = torch.where(torch.rand(B, H, W, generator=gen) < voting_share, 4.0, -4.0)  # fg logits
    votes = votes.to(device)
    raw = torch.randn(B, 31, H, W, generator=gen).to(device)
    present = torch.zeros(30, dtype=torch.bool, device=device)
    present[[2, 7, 11, 19, 25]] = True

    def per_view(fn) -> float:
        return 1000 * _timed(fn, device, repeats) / B

    return {
        "vote_map": per_view(lambda: vote_map(votes, 4.0)),
        "all_classes": per_view(lambda: center_probabilities(raw, True)),
        "five_classes": per_view(lambda: center_probabilities(raw, True, present, compact=True)),  # run's maps
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--devices", default="cpu,cuda", help="comma-separated; cuda is skipped where absent")
    ap.add_argument("--variants", default=None, help="comma-separated names (default: all)")
    ap.add_argument("--out", default=None, help="markdown file (default results/bench/net_<machine>.md)")
    args = ap.parse_args(argv)
    devices = [torch.device(d) for d in args.devices.split(",") if d != "cuda" or torch.cuda.is_available()]
    chosen = [v for v in VARIANTS if args.variants is None or v[0].split()[0] in args.variants.split(",")]
    rows = []
    for device in devices:
        for name, spec, size, views, batch, crop in chosen:
            r = bench_variant(spec, size, views, batch, crop, device, args.repeats)
            rows.append((device.type, name, size, r))
            print(
                f"{device.type:4} {name:22} {size[1]}x{size[0]}  {r['params']:>9,} params  {r['gmac']:5.2f} GMAC"
                f"  infer {r['ms_one']:7.1f} ms/view (1), {r['ms_scene']:7.1f} ms/view (scene)"
                f"  train {r['train_images_per_s']:6.1f} images/s at {r['train_size'][1]}x{r['train_size'][0]}",
                flush=True,
            )
    post = []
    for device in devices:
        r = bench_post_processing(device, args.repeats)
        post.append((device.type, r))
        print(
            f"{device.type:4} post-processing per 720x540 view: vote map {r['vote_map']:.1f} ms (7 % voting),"
            f" factored probabilities {r['all_classes']:.1f} ms (30 classes), {r['five_classes']:.1f} ms (5 of 30)",
            flush=True,
        )
    gpu = torch.cuda.get_device_name(0) if any(d.type == "cuda" for d in devices) else None
    machine = bench_machine.machine_slug(gpu)
    lines = [
        "# Stage 1 (U-Net) benchmark",
        "",
        f"Machine: {bench_machine.cpu_model()}, {bench_machine.usable_cores()} cores"
        + (f", {gpu}" if gpu else "")
        + f"; torch {torch.__version__}, {torch.get_num_threads()} CPU threads.",
        f"Command: `python scripts/bench_net.py --repeats {args.repeats} --devices {args.devices}"
        + (f" --variants {args.variants}`" if args.variants else "`"),
        "",
        "| device | variant | input | parameters | GMAC/view | ms/view (1 view) | ms/view (scene batch) | train images/s (size) |",
        "|---|---|---|---:|---:|---:|---:|---:|",
    ]
    for dev, name, size, r in rows:
        lines.append(
            f"| {dev} | {name} | {size[1]}x{size[0]} | {r['params']:,} | {r['gmac']:.2f} | {r['ms_one']:.1f} |"
            f" {r['ms_scene']:.1f} | {r['train_images_per_s']:.1f} ({r['train_size'][1]}x{r['train_size'][0]}) |"
        )
    lines += [
        "",
        "Post-processing per 720x540 view (batch of 5): the vote map with 7 % of the pixels voting, a factored head's"
        " probabilities over 30 classes, all of them or restricted to a scene's 5 (`run`'s case).",
        "",
        "| device | vote map (ms) | probabilities, 30 classes (ms) | probabilities, 5 of 30 (ms) |",
        "|---|---:|---:|---:|",
    ]
    lines += [f"| {d} | {r['vote_map']:.1f} | {r['all_classes']:.1f} | {r['five_classes']:.1f} |" for d, r in post]
    lines += ["", "Goal: the shipped DIMO model (dimo-context) at most 150 ms per 320x256 view on 2 CPU cores."]
    out = Path(args.out or Path(__file__).resolve().parents[1] / "results" / "bench" / f"net_{machine}.md")
    write_text_atomic(out, "\n".join(lines) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
