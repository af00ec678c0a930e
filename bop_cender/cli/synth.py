"""``bop-cender synth``: generate a synthetic dataset in the DIMO, T-LESS or BOP-Industrial layout."""

from __future__ import annotations

import argparse
import sys

from bop_cender.cli.options import add_executor_options, announce, count
from bop_cender.errors import ConfigError

EXAMPLES = """examples:
  bop-cender synth --layout dimo --out data/dimo_synth --scenes 20 --workers 2
  bop-cender synth --layout dimo --out data/dimo_synth --scenes 20 --variants 0,1,16,31 --views 13
  bop-cender synth --layout tless --out data/tless_synth --scenes 5 --views 20 --pbr-scenes 2
  bop-cender synth --layout tless --out data/tless_test --scenes 5 --seed 1
  bop-cender synth --layout industrial --out data/bins --scenes 2 --views 3 --train-scenes 2 --parts 10,20
  bop-cender synth --layout dimo --out data/dimo_synth --scenes 200 --executor ray --address HEAD:6379
--layout industrial writes the BOP-Industrial multi-sensor layout (as IPD, XYZ-IBD, ITODD-MV): bins of 10-16
DIMO parts (--parts MIN,MAX) seen by 4 sensors: hires (gray 320x256, the evaluated one), left and right (RGB
256x192), tof (gray + depth 240x180); test/ (with BOP'19 and BOP'24 targets) and train/. Read it with
--dataset bop --data-root OUT (the record bop_cender_synth.json names its evaluated sensor).
Running the same command again resumes: scene folders marked done (OUT/.bop_cender_synth/done/, every file
at its recorded size) are kept, the rest (never finished, truncated, deleted) is generated. Each
layout has one object catalogue (DIMO: 6 parts and 3 carriers; T-LESS: 30 objects; industrial: DIMO's
6 parts), the same for every --seed, so sets of two seeds share their models; --catalogue-seed draws another catalogue. Both seeds are
recorded in OUT/bop_cender_synth.json, and a resume with other values is refused. A non-empty --out folder
without that record (not a dataset bop-cender synth made) is refused unless --force.
"""


def register(sub) -> None:
    p = sub.add_parser(
        "synth",
        help="generate a synthetic dataset in the DIMO, T-LESS (BOP) or BOP-Industrial multi-sensor layout",
        description="Generate piles of procedural metal parts, rendered with the batched renderer and shaded in "
        "torch, written in exactly the DIMO, T-LESS or BOP-Industrial (multi-sensor bin-picking) layout. Deterministic per seed; resumable; writes a "
        "contact-sheet PNG per scene under OUT/contact_sheets/.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--layout", choices=("dimo", "tless", "industrial"), required=True)
    p.add_argument("--out", required=True, help="output dataset root")
    p.add_argument(
        "--scenes",
        type=count("--scenes", 0),
        default=None,
        help="dimo: scene numbers (each real + sim variants); tless, industrial: test scenes (required unless "
        "--models-only)",
    )
    p.add_argument(
        "--models-only", action="store_true", help="write the models folders (and the record) alone, no scene"
    )
    p.add_argument(
        "--views",
        type=count("--views"),
        default=None,
        help="dimo: viewpoints per scene (default 13); tless: images per test scene (default 10); industrial: "
        "captures per scene, each one image per sensor (default 3)",
    )
    # The options of one layout default to None, so that one given with the other layout is refused, not ignored.
    p.add_argument(
        "--variants",
        default=None,
        help="dimo: sim variant suffixes to write (0..70), comma-separated (default 0,3,17,40)",
    )
    p.add_argument("--carriers", default=None, help="dimo: carrier ids cycled over scenes (0..2; default 2)")
    p.add_argument(
        "--compositions", default=None, help="dimo: composition ids cycled over scenes (0..4; default 1,2,4)"
    )
    p.add_argument(
        "--pbr-scenes", type=count("--pbr-scenes", 0), default=None, help="tless: train_pbr scenes (default 1)"
    )
    p.add_argument(
        "--pbr-images", type=count("--pbr-images"), default=None, help="tless: images per train_pbr scene (default 4)"
    )
    p.add_argument(
        "--train-scenes", type=count("--train-scenes", 0), default=None, help="industrial: train scenes (default 1)"
    )
    p.add_argument("--parts", default=None, help="industrial: MIN,MAX parts per bin (default 10,16; at most 40)")
    p.add_argument(
        "--seed", type=count("--seed", 0), default=0, help="draws the scenes, poses, light and materials (default 0)"
    )
    p.add_argument(
        "--catalogue-seed",
        type=count("--catalogue-seed", 0),
        default=None,
        help="draws the object catalogue (default: the layout's one catalogue, the same for every --seed)",
    )
    p.add_argument(
        "--appearance",
        choices=("default", "randomised"),  # styles.APPEARANCES (not imported: it loads torch; tested equal)
        default="default",
        help="the look of the training folders (dimo: sim_jaigo, tless: train_pbr): the layout's own (default), "
        "or randomised materials, lights, environment, carrier, background and sensor (domain randomisation; "
        "industrial: train/); "
        "test folders keep their look",
    )
    add_executor_options(p, "scene job")
    p.add_argument("--no-contact-sheets", action="store_true")
    p.add_argument(
        "--force", action="store_true", help="write into a non-empty --out folder that bop-cender synth did not make"
    )
    p.set_defaults(func=cmd_synth)


def _ints(text: str, option: str) -> tuple[int, ...]:
    try:
        values = tuple(int(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise ConfigError(f"expected comma-separated integers, got {text!r}", field=option) from None
    if not values:
        raise ConfigError("expected at least one value", field=option)
    repeated = sorted({v for v in values if values.count(v) > 1})
    if repeated:  # each value is a folder or a draw: twice would be written twice, or counted twice
        raise ConfigError(f"{', '.join(map(str, repeated))} given twice in {text!r}: each value once", field=option)
    return values


def _parts(text: str) -> tuple[int, int]:
    """``--parts MIN,MAX`` (the range itself is checked by IndustrialSynthSpec)."""
    try:
        lo, hi = (int(x) for x in text.split(","))
    except ValueError:
        raise ConfigError(f"expected MIN,MAX (two integers, e.g. 10,16), got {text!r}", field="--parts") from None
    return lo, hi


#: Each layout's own options (their ``args`` names) with their defaults.
LAYOUT_OPTIONS = {
    "dimo": {"variants": "0,3,17,40", "carriers": "2", "compositions": "1,2,4"},
    "tless": {"pbr_scenes": 1, "pbr_images": 4},
    "industrial": {"train_scenes": 1, "parts": "10,16"},
}


def _layout_defaults(args: argparse.Namespace) -> None:
    """Fill in the defaults of ``args.layout``'s own options; refuse an option of the other layout.

    Raises:
        ConfigError: e.g. ``--pbr-scenes`` with ``--layout dimo`` (``field``: the option).
    """
    for layout, options in LAYOUT_OPTIONS.items():
        for name, default in options.items():
            value = getattr(args, name)
            if layout != args.layout and value is not None:
                flag = "--" + name.replace("_", "-")
                raise ConfigError(
                    f"is a {layout} option; --layout {args.layout} does not use it (got {flag} {value})", field=flag
                )
            if layout == args.layout and value is None:
                setattr(args, name, default)


def _dimo_views_note(n_viewpoints: int) -> str:
    """What ``--views`` other than DIMO's 13 means for the commands that read the set (the paper's selection)."""
    from bop_cender.data.dimo import PAPER_SELECTION

    kept = [v for v in PAPER_SELECTION.viewpoints if v < n_viewpoints]
    return (
        f"--views {n_viewpoints}: run, train and heatmaps read the paper's viewpoints "
        f"{', '.join(map(str, PAPER_SELECTION.viewpoints))} of a DIMO scene, so they will use {len(kept)} of the "
        f"{n_viewpoints} written per folder"
    )


def cmd_synth(args: argparse.Namespace) -> int:
    from bop_cender.synth.generate import generate
    from bop_cender.synth.record import check_output_folder
    from bop_cender.synth.write_dimo import DIMO_CATALOGUE_SEED, DimoSpec
    from bop_cender.synth.write_industrial import IndustrialSynthSpec
    from bop_cender.synth.write_tless import TLESS_CATALOGUE_SEED, TlessSpec

    # Each number is checked as the command line is read (options.count); what is left needs several.
    if args.models_only:
        for flag, value in (
            ("--scenes", args.scenes), ("--pbr-scenes", args.pbr_scenes), ("--train-scenes", args.train_scenes)
        ):  # fmt: skip
            if value:
                raise ConfigError(f"--models-only writes no scene; got {flag} {value}", field=flag)
        args.scenes = 0
        args.pbr_scenes = 0 if args.layout == "tless" else None
        args.train_scenes = 0 if args.layout == "industrial" else None
    _layout_defaults(args)
    if args.scenes is None:
        raise ConfigError("required: the number of scenes (--models-only for the models alone)", field="--scenes")
    extra = {"tless": args.pbr_scenes, "industrial": args.train_scenes}.get(args.layout) or 0
    if not args.models_only and args.scenes + extra < 1:
        other = {"tless": " or --pbr-scenes N", "industrial": " or --train-scenes N"}.get(args.layout, "")
        raise ConfigError(
            f"a dataset with no scene: give --scenes N{other} (N >= 1), or --models-only for the models alone",
            field="--scenes",
        )
    check_output_folder(args.out, force=args.force)
    default_catalogue = TLESS_CATALOGUE_SEED if args.layout == "tless" else DIMO_CATALOGUE_SEED
    catalogue_seed = default_catalogue if args.catalogue_seed is None else args.catalogue_seed
    try:
        if args.layout == "dimo":
            spec = DimoSpec(
                n_scenes=args.scenes,
                n_viewpoints=args.views or 13,
                variants=_ints(args.variants, "--variants"),
                carriers=_ints(args.carriers, "--carriers"),
                compositions=_ints(args.compositions, "--compositions"),
                seed=args.seed,
                contact_sheets=not args.no_contact_sheets,
                catalogue_seed=catalogue_seed,
                appearance=args.appearance,
            )
        elif args.layout == "industrial":
            parts = _parts(args.parts)
            spec = IndustrialSynthSpec(
                n_scenes=args.scenes,
                n_images=args.views or 3,
                train_scenes=args.train_scenes,
                parts_per_scene=(parts[0], parts[1]),
                seed=args.seed,
                contact_sheets=not args.no_contact_sheets,
                catalogue_seed=catalogue_seed,
                appearance=args.appearance,
            )
        else:
            spec = TlessSpec(
                n_scenes=args.scenes,
                n_views=args.views or 10,
                pbr_scenes=args.pbr_scenes,
                pbr_images=args.pbr_images,
                seed=args.seed,
                contact_sheets=not args.no_contact_sheets,
                catalogue_seed=catalogue_seed,
                appearance=args.appearance,
            )
    except ValueError as e:
        raise ConfigError(str(e), field="--parts" if "--parts" in str(e) else None) from None
    report = generate(
        args.layout, args.out, spec, workers=args.workers, announce=announce, executor=args.executor,
        address=args.address,
    )  # fmt: skip
    if args.layout == "dimo" and spec.n_viewpoints != 13:
        announce(_dimo_views_note(spec.n_viewpoints))
    print(
        f"{report.layout} dataset at {report.root}: {report.written} scene folders written, "
        f"{report.skipped} already complete"
        + (f", {report.others} more of an earlier run kept (not asked for now)" if report.others else "")
        + (f", {report.targets} BOP'19 targets" if report.targets is not None else ""),
        file=sys.stderr,
    )
    return 0
