"""``bop-cender train``: train stage 1 (the U-Net) on a split's views; checkpoints every epoch, ``--resume``."""

from __future__ import annotations

import argparse

from bop_cender.cli.options import announce, count, positive_number, resolve_device, split_name

EPILOG = """examples:
  bop-cender train --dataset dimo --epochs 1 --out runs/smoke          # one epoch on the embedded demo
  bop-cender train --dataset dimo --data-root data/dimo_train --split train --val-split sim \\
      --val-data-root data/dimo_test --epochs 12 --out runs/dimo
  bop-cender train --dataset dimo --data-root data/dimo_train --out runs/dimo --epochs 20 --resume
  bop-cender train --dataset tless --data-root ~/bop/tless --split train_pbr --variant tless --crop 270x360 \\
      --batch-size 4 --epochs 40 --device cuda --out runs/tless                # the paper's T-LESS model
Writes RUN_DIR/weights.pt (give it to run or heatmaps with --weights), checkpoint.pt, metrics.csv, config.json.
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "train",
        help="train the stage-1 network (center and curvature heatmaps) on a split",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--dataset", choices=("dimo", "tless", "bop"), required=True, help="dataset layout")
    p.add_argument("--data-root", default=None, help="dataset root (default: the embedded synthetic demo)")
    p.add_argument(
        "--split",
        type=split_name("--split"),
        default=None,
        help="training split (default: dimo train, tless/bop train_pbr)",
    )
    p.add_argument(
        "--val-split",
        type=split_name("--val-split"),
        default=None,
        help="validation split, scored every epoch (default: none)",
    )
    p.add_argument("--val-data-root", default=None, help="root of the validation split (default: --data-root)")
    p.add_argument(
        "--epochs", type=count("--epochs"), default=10, help="epochs in all (with --resume: up to this many)"
    )
    p.add_argument("--batch-size", type=count("--batch-size"), default=8)
    p.add_argument("--lr", type=positive_number("--lr"), default=3e-4, help="Adam learning rate (paper: 3e-4)")
    p.add_argument(
        "--variant",
        choices=(
            "dimo",
            "dimo-lean",
            "dimo-context",
            "dimo-refine",
            "dimo-centers",
            "dimo-votes",
            "tless",
            "tless-lean",
            "tless-factored",
            "tless-refine",
            "tless-votes",
        ),
        default=None,
        help="network: the paper's (dimo, tless) or our CPU ones (default: dimo-lean / tless-lean; dimo-context:"
        " dimo-lean with dilated context convolutions, a 3x wider receptive field; dimo-refine: dimo-context with a"
        " full-resolution curvature refinement; dimo-centers: dimo-context with a centre-only branch; dimo-votes:"
        " dimo-context with centre votes (each pixel of a part points at its centre); tless-factored: one"
        " class-agnostic center map times a per-pixel object class, for T-LESS's 30 ids; tless-refine: that one with"
        " the full-resolution curvature refinement; tless-votes: tless-factored with centre votes)",
    )
    p.add_argument("--width", type=positive_number("--width"), default=1.0, help="channel multiplier (default 1)")
    p.add_argument("--crop", default=None, metavar="HxW", help="train on random HxW crops (default: whole images)")
    p.add_argument("--no-augment", action="store_true", help="no data augmentation (ablation)")
    p.add_argument(
        "--camera-augment",
        action="store_true",
        help="after the paper's augmentations, another camera per image: colour cast, tone curve, defocus, resolution"
        " loss, signal-dependent noise, grey (issue 42's lever; results/robustness/)",
    )
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    p.add_argument("--seed", type=count("--seed", 0), default=0, help="everything random derives from it (default 0)")
    p.add_argument(
        "--limit-scenes", type=count("--limit-scenes"), default=None, help="only the first K training scenes"
    )
    p.add_argument(
        "--val-limit-scenes", type=count("--val-limit-scenes"), default=None, help="only the first K validation scenes"
    )
    p.add_argument(
        "--init-weights", default=None, metavar="W.pt", help="start from these weights (fine-tuning) instead of random"
    )
    p.add_argument(
        "--center-pos-weight",
        type=float,
        default=0.0,
        metavar="W",
        help="weight center pixels by 1 + W * target (default 0: the paper's plain BCE; helps T-LESS's 30 channels)",
    )
    p.add_argument(
        "--center-loss",
        choices=("bce", "focal"),
        default="bce",
        help="center heatmap loss: the paper's BCE (default) or CenterNet's focal loss (sharp peaks; see docs/method.md)",
    )
    p.add_argument(
        "--center-loss-weight",
        type=positive_number("--center-loss-weight"),
        default=1.0,
        metavar="W",
        help="weight of the center loss beside the curvature BCE (default 1)",
    )
    p.add_argument(
        "--class-loss-weight",
        type=positive_number("--class-loss-weight"),
        default=None,
        metavar="W",
        help="factored center heads only: weight of the per-pixel object-class cross-entropy (default 0.1)",
    )
    p.add_argument(
        "--center-votes",
        action="store_true",
        help="give --variant a vote head (each pixel of a part points at its centre; dimo-votes and tless-votes have"
        " one): e.g. --variant tless --factored-centers --center-votes for a GPU run",
    )
    p.add_argument(
        "--vote-loss-weight",
        type=positive_number("--vote-loss-weight"),
        default=None,
        metavar="W",
        help="networks with centre votes only (dimo-votes, tless-votes): weight of the vote loss (default 1)",
    )
    p.add_argument(
        "--factored-centers",
        action="store_true",
        help="give --variant a factored center head (one center map times a per-pixel object class; tless-factored"
        " has one): e.g. --variant tless --factored-centers, the paper's T-LESS network for a GPU run",
    )
    p.add_argument(
        "--train-only",
        default=None,
        metavar="MODULE[,MODULE]",
        help="train only these top-level modules of the network, the rest frozen (batch-norm statistics too): e.g."
        " --variant dimo-refine --init-weights CONTEXT.pt --train-only refine,curvature_head leaves the centres as"
        " they were, --variant dimo-centers ... --train-only center_branch,center_head the curvature (modules: e1 e2 e3"
        " bottleneck context d2 d1 center_head curvature_head refine center_branch vote_head; default: all)",
    )
    p.add_argument("--out", required=True, metavar="RUN_DIR", help="run folder (checkpoints, weights, metrics)")
    p.add_argument("--resume", action="store_true", help="continue the run in RUN_DIR from its last checkpoint")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_train)


def parse_crop(text: str | None) -> tuple[int, int] | None:
    from bop_cender.errors import ConfigError

    if text is None:
        return None
    try:
        h, w = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise ConfigError(f"expected HxW (e.g. 128x160), got {text!r}", field="--crop") from None
    if h < 1 or w < 1:
        raise ConfigError(f"expected a positive height and width, got {text!r}", field="--crop")
    return h, w


def cmd_train(args: argparse.Namespace) -> int:
    from pathlib import Path

    from bop_cender.data.bop_io import check_output_dir
    from bop_cender.datasets import resolve_data_root
    from bop_cender.errors import ConfigError
    from bop_cender.net.train import TrainConfig, network_spec_of, train
    from bop_cender.net.unet import UNetSpec
    from bop_cender.net.weights import weights_kind
    from bop_cender.synth.demo import cache_dir

    kind = weights_kind(args.dataset)
    crop = parse_crop(args.crop)  # before the data is resolved (the demo may be generated first)
    variant = args.variant or f"{kind}-lean"
    channels = 1 if kind == "dimo" else 2  # "one per object id": the data's count is known once it is read
    spec = network_spec_of(variant, args.width, channels, args.factored_centers, args.center_votes)  # before the data
    factored, votes = spec.factored_centers, spec.center_votes
    if args.class_loss_weight is not None and not factored:  # it would be recorded in config.json and not used
        raise ConfigError(
            "weights the class loss of a factored center head; this network has none (--variant tless-factored, or"
            " --factored-centers)",
            field="--class-loss-weight",
        )
    if args.vote_loss_weight is not None and not votes:
        raise ConfigError(
            "weights the loss of centre votes; this network has none (--variant dimo-votes or tless-votes, or"
            " --center-votes)",
            field="--vote-loss-weight",
        )
    check_output_dir(args.out)
    root = resolve_data_root(args.dataset, args.data_root, announce)
    config = TrainConfig(
        dataset=args.dataset, data_root=str(root), split=args.split or ("train" if kind == "dimo" else "train_pbr"),
        val_split=args.val_split, val_data_root=args.val_data_root, epochs=args.epochs, batch_size=args.batch_size,
        lr=args.lr, variant=variant, width=args.width, crop=crop,
        augment=not args.no_augment, camera_augment=args.camera_augment, seed=args.seed, limit_scenes=args.limit_scenes,
        val_limit_scenes=args.val_limit_scenes, init_weights=args.init_weights,
        center_pos_weight=args.center_pos_weight, center_loss=args.center_loss,
        center_loss_weight=args.center_loss_weight, factored_centers=args.factored_centers,
        center_votes=args.center_votes and not UNetSpec.named(variant, center_channels=channels).center_votes,
        train_only=tuple(n.strip() for n in args.train_only.split(",")) if args.train_only is not None else (),
        **({} if args.class_loss_weight is None else {"class_loss_weight": args.class_loss_weight}),
        **({} if args.vote_loss_weight is None else {"vote_loss_weight": args.vote_loss_weight}),
    )  # fmt: skip
    summary = train(
        config, Path(args.out), resume=args.resume, device=resolve_device(args.device), cache_dir=cache_dir(),
        progress=not args.no_progress, announce=announce,
    )  # fmt: skip
    last = summary.history[-1] if summary.history else None
    done = f"{summary.epochs_done} epoch{'s' if summary.epochs_done != 1 else ''}" + (
        f" (resumed after {summary.resumed_from})" if summary.resumed_from else ""
    )
    if summary.resumed_from and summary.resumed_from >= summary.epochs_done:  # a finished run's command again
        print(f"nothing to train: {summary.run_dir} holds its {summary.epochs_done} epochs already (--epochs)")
    else:
        print(f"trained {done} in {summary.wall_s:.0f} s" + (f"; last loss {last.train_loss:.4f}" if last else ""))
    print(f"wrote {summary.run_dir / 'weights.pt'} (use: --heatmaps net --weights {summary.run_dir / 'weights.pt'})")
    return 0
