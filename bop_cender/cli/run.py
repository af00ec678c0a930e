"""``bop-cender run``: the method over a dataset split, to a BOP results CSV that ``score`` reads with no flag."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from bop_cender.cli.options import add_data_options, add_executor_options, announce, count, resolve_device

if TYPE_CHECKING:
    from bop_cender.method import CenDerNetConfig

EPILOG = """examples:
  bop-cender run --dataset dimo --split real            # the embedded demo, the shipped network
  bop-cender run --dataset dimo --split sim --data-root ~/dimo --workers 2 --out cendernet-oracle_dimo-sim.csv
  bop-cender run --dataset tless --data-root ~/bop/tless --split test --n-views 5 --score
  bop-cender run --dataset dimo --split sim --resume      # continue an interrupted run
  bop-cender run --dataset dimo --split sim --data-root ~/dimo --executor ray --address HEAD:6379  # on a cluster
Heatmaps: --heatmaps net (the default where weights are shipped for the dataset: --weights or the shipped ones);
--heatmaps oracle renders them from the ground truth (stages 2 and 3 alone, no network).
"""


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``run`` to ``bop-cender``'s subparsers."""
    p = sub.add_parser(
        "run",
        help="estimate poses (heatmaps -> 3D centres -> render-and-compare) over a split; write a BOP results CSV",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_data_options(p)
    p.add_argument(
        "--heatmaps",
        choices=("net", "oracle", "oracle-centers", "oracle-curvature"),
        default=None,
        help="heatmap source: net (the network: --weights, else the shipped weights) or oracle (rendered from"
        " the GT); default: net where weights are shipped for the dataset or --weights is given, else oracle."
        " Ablations: oracle-centers (oracle centres, the network's curvature), oracle-curvature (the reverse)",
    )
    p.add_argument("--weights", default=None, help="network weights (every --heatmaps source but oracle)")
    p.add_argument(
        "--device", choices=("auto", "cpu", "cuda"), default="auto", help="torch device of the heatmaps (default: auto)"
    )
    p.add_argument(
        "--pose-device",
        choices=("cpu", "cuda", "same"),
        default="cpu",
        help="torch device of stage 3's renders and costs (default: cpu; same: --device's). On an H200 the pose"
        " search ran slower on CUDA than on 2 CPU cores (its small Nelder-Mead batches were bound by kernel launches;"
        " results/bench/run_*nvidia-h200.md); its renders and costs have since become one CUDA kernel each"
        " (numba-cuda), not yet timed on a GPU",
    )
    p.add_argument(
        "--out",
        default=None,
        help="results CSV, named for the run's dataset and split (default: cendernet-<heatmaps>_<dataset>-<split>.csv here; split train_pbr: -train-pbr)",
    )
    add_executor_options(p, "scene")
    p.add_argument(
        "--threads",
        type=count("--threads"),
        default=1,
        help="threads of the compiled CPU loops (renderer, stage 3's costs) with one process (default 1; a many-core "
        "host running one scene at a time: its cores); the same rows whatever the count",
    )
    p.add_argument(
        "--limit-scenes", type=count("--limit-scenes"), default=None, help="only the first K scenes of the split"
    )
    p.add_argument("--resume", action="store_true", help="keep the finished scenes of an interrupted run")
    p.add_argument(
        "--candidates",
        type=count("--candidates"),
        default=None,
        help="random pose candidates per object (default 2000)",
    )
    p.add_argument("--top-k", type=count("--top-k"), default=None, help="candidates refined by Nelder-Mead (default 3)")
    p.add_argument("--no-occlusion", action="store_true", help="do not let placed objects occlude the next (ablation)")
    p.add_argument(
        "--deterministic-time", action="store_true", help="write -1 as every row's time (reproducible files)"
    )
    p.add_argument(
        "--vis",
        default=None,
        metavar="DIR",
        help="write a figure per scene (views, heatmaps, centres, outlines: right / wrong / missed)",
    )
    p.add_argument(
        "--max-views",
        type=count("--max-views"),
        default=None,
        help="estimate from the first K views of each scene (ablation; at least centers.min_views, 2 by default)",
    )
    p.add_argument(
        "--preset",
        choices=("ours", "paper"),
        default="ours",
        help="the method's settings to start from (default ours; paper: the paper's stage 3, one sweep, no scene"
        " polish, no centre term, no screen, searched on our edge proxy and judged by the paper's render cost;"
        " --set poses.search_cost=render renders every evaluation as the paper does; bop_cender/pose/config.py PRESETS); recorded in the run's sidecar",
    )
    p.add_argument(
        "--set",
        action="append",
        metavar="SECTION.FIELD=VALUE",
        help="override a method setting after --preset (repeatable, any depth): centers.d_c=30, poses.candidates.n=500,"
        " poses.sweeps.passes=1, poses.network.t_b=0.5 (a network's curvature; default: the weights' calibration),"
        " poses.t_b=0.7 (rendered curvature and pose edges), targets.curvature_scale=1",
    )
    p.add_argument(
        "--task",
        choices=("localization", "detection"),
        default=None,
        help="localization (BOP'19: each image's instance counts and objects are known; scored by AR) or detection"
        " (BOP'24/'25: neither is known; stage 2 finds centres without counts, stage 3 tries every target object;"
        " scored by mAP); the sidecar names the protocol, so score needs no flag (default: detection where the data"
        " has test_targets_bop24.json and no test_targets_bop19.json, else localization)",
    )
    p.add_argument("--score", action="store_true", help="score the results when done (bop-cender score)")
    p.add_argument(
        "--report",
        action="store_true",
        help="write the run's page when done (bop-cender report): <csv stem>_report/index.html beside the CSV, with"
        " the --vis figures where given",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_run)


def default_heatmaps(dataset: str, weights: str | None) -> str:
    """``net`` where weights are given or shipped for the dataset (``dimo``, ``tless``), else ``oracle``: the shipped
    T-LESS weights have one center channel per T-LESS object, so another BOP dataset (``bop``) needs ``--weights``."""
    if weights is not None:
        return "net"
    if dataset not in ("dimo", "tless"):
        return "oracle"
    from bop_cender.errors import ConfigError
    from bop_cender.net.weights import shipped_weights_path

    try:
        shipped_weights_path(dataset)
    except ConfigError:
        return "oracle"
    return "net"


def default_task(data_root: str | None) -> str:
    """``detection`` where the data holds BOP'24 targets only (``test_targets_bop24.json``, no BOP'19 file: the
    industrial datasets), said on stderr; else ``localization``."""
    from pathlib import Path

    from bop_cender.data.layout import TARGETS_FILE, TARGETS_FILE_BOP24

    root = Path(data_root) if data_root else None
    if root is not None and (root / TARGETS_FILE_BOP24).is_file() and not (root / TARGETS_FILE).is_file():
        announce(f"{TARGETS_FILE_BOP24} and no {TARGETS_FILE}: the BOP'24 6D-detection task (--task detection)")
        return "detection"
    return "localization"


def run_config(args: argparse.Namespace) -> CenDerNetConfig:
    """The method's settings of a ``run`` command line: ``--preset`` for ``--dataset``, then ``--seed``,
    ``--candidates``, ``--top-k`` and ``--no-occlusion``, then every ``--set`` in order (which may override them).

    Raises:
        ConfigError: a bad setting, or more starts to refine than candidates (naming the option that gave them).
    """
    from bop_cender.data.industrial import config_layout
    from bop_cender.data.registry import DEFAULT_SPLIT
    from bop_cender.method import CenDerNetConfig

    options = [f"poses.seed={args.seed}"]
    for name, value in (("candidates.n", args.candidates), ("candidates.top_k", args.top_k)):  # count() refused < 1
        if value is not None:
            options.append(f"poses.{name}={value}")
    if args.no_occlusion:
        options.append("poses.occlusion=false")
    layout = config_layout(args.dataset, args.data_root, args.split or DEFAULT_SPLIT[args.dataset])
    config = CenDerNetConfig.for_dataset(layout, args.preset).for_task(args.task or "localization")
    config = config.with_settings([*options, *(args.set or [])])
    config.poses.check_refinable(  # once every setting is in, whatever their order; naming the option given
        "--top-k" if args.top_k is not None else "--candidates" if args.candidates is not None else "--set"
    )
    return config


def cmd_run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from bop_cender.data.registry import DEFAULT_SPLIT
    from bop_cender.progress import progress_bar
    from bop_cender.results.files import default_result_filename
    from bop_cender.runner import RunRequest, results_dataset_name, run

    split = args.split or DEFAULT_SPLIT[args.dataset]
    if args.task is None:
        args.task = default_task(args.data_root)
    if args.heatmaps is None:
        args.heatmaps = default_heatmaps(args.dataset, args.weights)
        if args.heatmaps == "oracle":
            announce(f"no network weights are shipped for {args.dataset}: heatmaps from the oracle (--heatmaps oracle)")
    device = str(resolve_device(args.device))
    pose_device = device if args.pose_device == "same" else str(resolve_device(args.pose_device, "--pose-device"))
    config = run_config(args)
    out = Path(
        args.out
        or default_result_filename(
            f"cendernet-{args.heatmaps}", results_dataset_name(args.dataset, args.data_root), split
        )
    )
    if args.data_root is None:
        announce(f"no --data-root: using the embedded synthetic {args.dataset} demo")
    request = RunRequest(
        dataset=args.dataset, data_root=args.data_root, split=split, out=out, n_views=args.n_views,
        model_type=args.model_type, heatmaps=args.heatmaps, weights=args.weights, seed=args.seed, config=config,
        workers=args.workers, limit_scenes=args.limit_scenes, resume=args.resume,
        deterministic_time=args.deterministic_time, device=device, pose_device=pose_device,
        vis_dir=Path(args.vis) if args.vis else None, max_views=args.max_views, threads=args.threads, task=args.task,
        executor=args.executor, address=args.address,
    )  # fmt: skip
    bar = None

    def progress(done: int, total: int, key: str) -> None:
        nonlocal bar
        if args.no_progress:
            return
        if bar is None:
            bar = progress_bar(total=total, initial=done, unit="scene", desc="run")
        else:
            bar.update(done - bar.n)
        if key:
            bar.set_postfix_str(f"last {key}")

    try:
        summary = run(request, progress=progress)
    finally:
        if bar is not None:
            bar.close()
    for key, error in summary.failed.items():
        print(f"warning: scene {key}: no estimates ({error})", file=sys.stderr)
    if summary.empty:
        print(f"warning: {len(summary.empty)} scene(s) with no detected object: {', '.join(summary.empty[:10])}",
              file=sys.stderr)  # fmt: skip
    stages = ", ".join(f"{k} {v:.1f} s" for k, v in summary.stage_seconds.items())
    print(f"{summary.scenes} scenes ({summary.resumed} resumed), {summary.estimates} objects, {summary.rows} rows;"
          f" {summary.wall_seconds:.1f} s ({stages})")  # fmt: skip
    if summary.curvature_threshold_source != "poses.t_b":  # a network's curvature, binarised its own way
        print(f"the network's curvature binarised at {summary.curvature_threshold:.3g}"
              f" ({summary.curvature_threshold_source})")  # fmt: skip
    print(f"wrote {summary.out} and {summary.sidecar}")
    scored = None
    if args.score:
        from bop_cender.cli.score import print_scored
        from bop_cender.eval.score_file import score_file

        scored = score_file(summary.out, progress=not args.no_progress)
        print_scored(scored, summary.out)
    else:
        print(f"next: bop-cender score {summary.out}")
    if args.report:  # after a partial failure too: the page lists the failed scenes
        from bop_cender.cli.report import print_written
        from bop_cender.report.run_report import write_report

        print_written(write_report(summary.out, vis_dir=request.vis_dir, progress=not args.no_progress, scored=scored))
    if summary.failed:  # the file is whole for the other scenes, but the run did not do what was asked
        print(f"error: {len(summary.failed)} of {summary.scenes} scene(s) failed (above; listed in {summary.sidecar},"
              " their targets count as misses); mend the input and rerun with --resume to redo only them",
              file=sys.stderr)  # fmt: skip
        return 1
    return 0
