"""``bop-cender heatmaps``: stage 1 alone over a split: inference time, figures against the GT, PNGs."""

from __future__ import annotations

import argparse

from bop_cender.cli.options import add_data_options, announce, count, resolve_device

EPILOG = """examples:
  bop-cender heatmaps --dataset dimo --split sim                  # shipped weights on the embedded demo
  bop-cender heatmaps --dataset dimo --split real --data-root data/dimo_test --png --out heatmaps_real
  bop-cender heatmaps --dataset dimo --split sim --weights runs/dimo/weights.pt --limit-scenes 3
  bop-cender heatmaps --dataset dimo --split sim --weights oracle  # the GT heatmaps (figures all 1)
Writes OUT/heatmaps_<dataset>-<split>.json (figures, ms per view) and, with --png, one PNG per view:
input | predicted center | predicted curvature | GT center | GT curvature.
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "heatmaps",
        help="stage 1 alone: predict center and curvature heatmaps, score them against the GT, write PNGs",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_data_options(p)
    p.add_argument("--weights", default=None, help="weights file, or 'oracle' (default: the shipped weights)")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    p.add_argument("--out", default="heatmaps", help="output folder (default: ./heatmaps)")
    p.add_argument("--png", action="store_true", help="write one side-by-side PNG per view")
    p.add_argument("--limit-scenes", type=count("--limit-scenes"), default=None, help="only the first K scenes")
    p.add_argument(
        "--peak-threshold",
        type=float,
        default=None,
        help="center peaks above this count (default: stage 2's, CenterConfig.peak_threshold)",
    )
    p.add_argument(
        "--test-flips",
        type=int,
        choices=(1, 2, 4),
        default=1,
        help="network passes per view whose center maps are averaged: 1 the network alone (default, as `run`'s"
        " test_flips and the cards), 2 and its left-right flip, 4 and its up-down flips too",
    )
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=cmd_heatmaps)


def cmd_heatmaps(args: argparse.Namespace) -> int:
    import json
    from dataclasses import replace
    from pathlib import Path

    from bop_cender.cli.options import data_request
    from bop_cender.data.bop_io import check_output_dir, write_text_atomic
    from bop_cender.datasets import open_with_demo
    from bop_cender.errors import ConfigError
    from bop_cender.meshes import MeshCache
    from bop_cender.net.heatmap_eval import evaluate_heatmaps, format_report
    from bop_cender.net.metrics import HeatmapMetricsConfig
    from bop_cender.net.targets import TargetConfig

    if args.weights == "oracle" and args.test_flips != 1:
        raise ConfigError("test flips average a network's passes; the oracle has none (drop it or give --weights)",
                          field="--test-flips")  # fmt: skip
    out = check_output_dir(args.out)
    device = resolve_device(args.device)
    dataset = open_with_demo(data_request(args), announce=announce)
    meshes = MeshCache(dataset.models)
    if args.weights == "oracle":
        from bop_cender.data.industrial import config_layout
        from bop_cender.net.oracle import OraclePredictor

        targets = TargetConfig.for_dataset(config_layout(args.dataset, args.data_root, dataset.split))
        predictor = OraclePredictor(dataset.models, meshes, targets, device=device)
        source = "oracle"
    else:
        from bop_cender.net.predictor import NetPredictor
        from bop_cender.net.weights import check_covers_targets, load_weights, shipped_weights_path

        path = Path(args.weights) if args.weights else shipped_weights_path(args.dataset)
        weights = load_weights(path, dataset=args.dataset)
        check_covers_targets(weights, dataset.models)
        targets = weights.targets
        predictor = NetPredictor(weights, device=device, flips=args.test_flips)
        source = str(path) + ("" if args.test_flips == 1 else f" ({args.test_flips} test flips)")
    keys = dataset.scene_keys[: args.limit_scenes] if args.limit_scenes else dataset.scene_keys
    metrics_config = HeatmapMetricsConfig()
    if args.peak_threshold is not None:
        if not 0 < args.peak_threshold < 1:
            raise ConfigError(f"expected a number in (0, 1), got {args.peak_threshold}", field="--peak-threshold")
        metrics_config = replace(metrics_config, peak_threshold=args.peak_threshold)
    png_dir = out / "png" if args.png else None
    json_path = out / f"heatmaps_{dataset.name}-{dataset.split}.json"
    listed = _listed_pngs(json_path) if png_dir is not None else []  # the PNGs of the report this run replaces
    created = [d for d in (out, png_dir) if d is not None and not d.exists()]
    earlier = set(png_dir.iterdir()) if png_dir is not None and png_dir.is_dir() else set()
    try:
        report = evaluate_heatmaps(
            dataset, predictor, targets, meshes, source, keys, png_dir, metrics_config, progress=not args.no_progress,
        )  # fmt: skip
    except BaseException:  # a scene that fails midway leaves no PNGs of a run that wrote no report
        _remove_new(png_dir, earlier, created)
        raise
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(json_path, json.dumps(report.as_dict(), indent=2) + "\n")
    written = {p.name for p in report.pngs}
    stale = sorted(png_dir / name for name in listed if name not in written and (png_dir / name).is_file())
    for path in stale:  # the PNGs the report this one replaces listed, not written now: they would read as this
        # run's (another dataset's or split's PNGs in the folder stay: their own reports list them)
        path.unlink(missing_ok=True)
    print(format_report(report))
    print(f"wrote {json_path}" + (f" and {len(report.pngs)} PNGs under {out / 'png'}" if report.pngs else ""))
    if stale:
        print(f"removed {len(stale)} PNG(s) of an earlier run under {png_dir} (views this run did not cover)")
    return 0


def _listed_pngs(json_path) -> list[str]:
    """The PNG names an earlier report of this dataset and split listed (none where it is absent, unreadable or
    older than the list: its PNGs are then left as they are)."""
    import json

    try:
        names = json.loads(json_path.read_text()).get("pngs", [])
    except (OSError, ValueError, AttributeError):
        return []
    return (
        [n for n in names if isinstance(n, str) and n.endswith(".png") and "/" not in n]
        if isinstance(names, list)
        else []
    )


def _remove_new(png_dir, earlier: set, created: list) -> None:
    """Remove the PNGs a failed run wrote (not those of an earlier run) and the folders it created, if empty."""
    import contextlib

    if png_dir is not None and png_dir.is_dir():
        for path in set(png_dir.iterdir()) - earlier:
            with contextlib.suppress(OSError):
                path.unlink()
    for folder in reversed(created):
        with contextlib.suppress(OSError):
            folder.rmdir()
