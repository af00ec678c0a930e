"""The robustness benchmark of stage 1: the same test scenes in several looks, scored, and the drop from the own look.

Why: the network must hold on images it never saw (a real camera is another look). Every look is a copy of the
test set with the same scenes, poses, cameras and models; only the images differ. The figure per look is the
paper's strict one on DIMO layouts (AR_MSSD<5%) and the BOP AR on T-LESS layouts, and the drop is measured against
the own look on the same scenes. ``--measure heatmaps`` measures stage 1 alone instead (``bop-cender heatmaps``: the
centre peaks' F1 and the curvature's AP against the oracle maps, per view): a few seconds per look instead of
minutes, and hundreds of centres rather than tens of parts, so the figure to screen a lever with before the poses.

Looks (none of the foreign ones is ever used for training; training sets use the own look, ``synth --appearance
default`` or ``randomised``):
- ``own``: the images as ``bop-cender synth`` made them (our torch renderer and sensor model);
- ``sensor``: the own images through a foreign camera (``bop_cender/synth/sensor_look.py``: exposure, white
  balance, defocus, Bayer demosaic, banding noise, sRGB tone curve, JPEG);
- ``pyrender``: rendered again by OpenGL (``scripts/rerender_pyrender.py``; needs ``pip install -e ".[pyrender]"``
  and EGL);
- ``cycles``: path-traced by Blender's Cycles (``scripts/rerender_cycles.py``; needs ``bpy``) where present.

    python scripts/robustness.py --dataset dimo --data-root DATA/dimo_test --splits sim,real \\
        --looks own,sensor,pyrender --weights bop_cender/net/weights/dimo.pt --out results/robustness/dimo_test

Each look's copy is made once under ``--looks-root`` (default: beside the data, ``DATA/dimo_test.looks/``) and kept;
each run's results CSV and scores go under ``--out``; a run whose scores exist is not run again (resumable: rerun the
same command). Prints the table and writes ``--out/robustness.md`` and ``robustness.csv``.
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
from pathlib import Path

LOOKS = ("own", "sensor", "pyrender", "cycles")
#: The figure per layout: the paper's strict one for DIMO, BOP's AR for T-LESS.
FIGURE = {"dimo": "AR_MSSD<5%", "tless": "AR"}
#: The figures of ``--measure heatmaps`` and their keys in ``bop-cender heatmaps``' JSON.
HEATMAP_FIGURES = {"centre F1": "center_f1", "curvature AP": "curvature_ap"}
SCRIPTS = Path(__file__).resolve().parent


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", choices=tuple(FIGURE), required=True)
    ap.add_argument("--data-root", type=Path, required=True, help="the test set in its own look")
    ap.add_argument("--splits", default=None, help="comma-separated (default: dimo sim,real; tless test)")
    ap.add_argument("--looks", default="own,sensor,pyrender", help=f"comma-separated, of {', '.join(LOOKS)}")
    ap.add_argument("--weights", type=Path, default=None, help="the network (default: the shipped weights)")
    ap.add_argument("--heatmaps", choices=("net", "oracle", "oracle-centers", "oracle-curvature"), default="net",
                    help="run's --heatmaps (net; oracle checks that a look changes no ground truth; --measure heatmaps:"
                    " net or oracle)")  # fmt: skip
    ap.add_argument("--measure", choices=("pose", "heatmaps"), default="pose",
                    help="pose: run and score (default); heatmaps: stage 1 alone, centre F1 and curvature AP")  # fmt: skip
    ap.add_argument("--looks-root", type=Path, default=None, help="where the looks' copies go (default DATA.looks/)")
    ap.add_argument("--out", type=Path, required=True, help="folder of the results, scores and the table")
    ap.add_argument("--seed", type=int, default=0, help="draws of the sensor look and the renderers' noise")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--limit-scenes", type=int, default=None)
    args = ap.parse_args(argv)
    looks = [s.strip() for s in args.looks.split(",") if s.strip()]
    unknown = [look for look in looks if look not in LOOKS]
    if unknown or not looks:
        print(
            f"error: --looks: unknown look {', '.join(unknown) or '(none)'}; known: {', '.join(LOOKS)}", file=sys.stderr
        )
        return 2
    splits = [s.strip() for s in (args.splits or ("sim,real" if args.dataset == "dimo" else "test")).split(",")]
    if not all(splits):
        print(f"error: --splits: an empty split name in {args.splits!r}", file=sys.stderr)
        return 2
    if args.limit_scenes is not None and args.limit_scenes < 1:
        print(f"error: --limit-scenes: expected 1 or more, got {args.limit_scenes}", file=sys.stderr)
        return 2
    if args.measure == "heatmaps" and args.heatmaps not in ("net", "oracle"):
        print(
            f"error: --heatmaps {args.heatmaps}: --measure heatmaps measures the network or the oracle", file=sys.stderr
        )
        return 2
    if not args.data_root.is_dir():
        print(f"error: --data-root: {args.data_root} is not a folder", file=sys.stderr)
        return 2
    looks_root = args.looks_root or args.data_root.with_name(args.data_root.name + ".looks")
    args.out.mkdir(parents=True, exist_ok=True)
    figures = [FIGURE[args.dataset]] if args.measure == "pose" else list(HEATMAP_FIGURES)
    rows = []
    for split in splits:
        for look in looks:
            root = args.data_root if look == "own" else looks_root / f"{look}_{split}"
            if not root.exists():
                code = make_look(look, args.dataset, args.data_root, root, split, args.seed, args.limit_scenes)
                if code:
                    return code
            measured = (
                run_and_score(args, root, look, split)
                if args.measure == "pose"
                else heatmap_figures(args, root, look, split)
            )
            if measured is None:
                return 2
            rows.append({"look": look, "split": split, **measured})
    lines = table(rows, figures, looks, splits)
    print("\n".join(lines))
    (args.out / "robustness.md").write_text("\n".join(lines) + "\n")
    with open(args.out / "robustness.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, ["look", "split", *figures])
        writer.writeheader()
        writer.writerows(rows)
    print(f"wrote {args.out / 'robustness.md'} and {args.out / 'robustness.csv'}")
    return 0


def make_look(look: str, dataset: str, src: Path, dst: Path, split: str, seed: int, limit: int | None) -> int:
    """Make ``dst``, the copy of ``src`` whose ``split`` is drawn in ``look``; the exit code (0: made)."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    if look == "sensor":
        from bop_cender.errors import BopCenderError
        from bop_cender.synth.relook import open_every_image, relook_split, sensor_redraw

        try:
            dataset_split = open_every_image(dataset, src, split)
            n = relook_split(dataset_split, src, dst, sensor_redraw(seed), limit, lambda line: print(line, flush=True))
        except (BopCenderError, ValueError, OSError) as exc:
            print(f"error: sensor look of {src}: {exc}", file=sys.stderr)
            return 2
        print(f"wrote {dst} ({n} images of split {split} through the foreign camera)")
        return 0
    script = SCRIPTS / f"rerender_{look}.py"
    if not script.exists():
        print(f"error: --looks {look}: {script} is not in this checkout", file=sys.stderr)
        return 2
    command = [sys.executable, str(script), str(src), str(dst), "--dataset", dataset, "--split", split]
    command += ["--seed", str(seed)] + ([] if limit is None else ["--limit-scenes", str(limit)])
    return subprocess.call(command)


def heatmap_figures(args: argparse.Namespace, root: Path, look: str, split: str) -> dict[str, float] | None:
    """``bop-cender heatmaps`` on one look's copy; its figures by name (None: the command failed or wrote no figure)."""
    import json

    out = args.out / f"heatmaps-{args.heatmaps}{look}_{args.dataset}-{split}"
    report = out / f"heatmaps_{args.dataset}-{split}.json"
    if not report.exists():
        weights = "oracle" if args.heatmaps == "oracle" else args.weights  # `heatmaps` takes the oracle as weights
        command = cli_command(args, "heatmaps", root, split, weights, "--out", str(out), "--no-progress")
        if subprocess.call(command):
            print(f"error: the heatmaps of {root} ({look}, {split}) failed", file=sys.stderr)
            return None
    try:
        metrics = json.loads(report.read_text())["metrics"]
        return {name: float(metrics[key]) for name, key in HEATMAP_FIGURES.items()}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        print(f"error: {report}: no heatmap figures ({type(exc).__name__}: {exc})", file=sys.stderr)
        return None


def run_and_score(args: argparse.Namespace, root: Path, look: str, split: str) -> dict[str, float] | None:
    """``bop-cender run`` on one look's copy, then its score; the figure by name (None: the run or the score
    failed)."""
    from bop_cender.errors import BopCenderError
    from bop_cender.eval.score_file import score_file

    csv_path = args.out / f"{args.heatmaps}{look}_{args.dataset}-{split}.csv"
    if not csv_path.exists():
        command = cli_command(args, "run", root, split, args.weights, "--heatmaps", args.heatmaps, "--out",
                              str(csv_path), "--workers", str(args.workers), "--deterministic-time", "--resume")  # fmt: skip
        if subprocess.call(command):
            print(f"error: the run on {root} ({look}, {split}) failed", file=sys.stderr)
            return None
    try:
        scored = score_file(csv_path)
    except BopCenderError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return None
    figure = scored.report.scores.get(FIGURE[args.dataset])
    if figure is None:  # BOP's AR needs VSD, and VSD the test depth images
        print(f"error: {csv_path}: {FIGURE[args.dataset]} is not available ({'; '.join(scored.report.notes)})",
              file=sys.stderr)  # fmt: skip
        return None
    return {FIGURE[args.dataset]: float(figure)}


def cli_command(
    args: argparse.Namespace, subcommand: str, root: Path, split: str, weights: Path | str | None, *extra: str
) -> list[str]:
    """``bop-cender SUBCOMMAND`` on one look's copy (``root``, ``split``) with ``weights`` (None: the shipped ones),
    ``--limit-scenes`` where given, and ``extra``."""
    command = [sys.executable, "-m", "bop_cender.cli", subcommand, "--dataset", args.dataset, "--data-root", str(root)]
    command += ["--split", split, *extra] + ([] if weights is None else ["--weights", str(weights)])
    return command + ([] if args.limit_scenes is None else ["--limit-scenes", str(args.limit_scenes)])


def table(rows: list[dict], figures: list[str], looks: list[str], splits: list[str]) -> list[str]:
    """A markdown table: one row per look, per split and figure its value and the drop from the own look (absolute,
    %)."""
    by_look = {(r["look"], r["split"]): r for r in rows}
    head = f"| look | {' | '.join(f'{s} {name} | drop' for s in splits for name in figures)} |"
    lines = [head, "|---|" + "---:|---:|" * len(splits) * len(figures)]
    for look in looks:
        cells = []
        for split in splits:
            for name in figures:
                value, own = by_look[(look, split)][name], by_look.get(("own", split), {}).get(name)
                drop = "" if not own or look == "own" else f"{value - own:+.3f} ({(value / own - 1) * 100:+.0f} %)"
                cells.append(f"{value:.3f} | {drop}")
        lines.append(f"| {look} | {' | '.join(cells)} |")
    return lines


if __name__ == "__main__":
    sys.exit(main())
