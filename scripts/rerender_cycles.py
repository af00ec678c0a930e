"""Render a DIMO- or T-LESS-layout dataset's images again, path traced with Blender's Cycles (a look never trained on).

Why: issue 42 asks stage 1 to hold on images it never saw. ``rerender_pyrender.py`` gives one foreign look
(OpenGL rasterising); this gives a physically based one, path traced like the BOP challenge's own PBR training
images: Cycles on the CPU, OpenImageDenoise where the wheel has it. It copies a dataset (every JSON, the
models, the masks) and renders every image of one split again (T-LESS: every image the method runs on, those
of ``test_targets_bop19.json`` where there is one): each scene's GT objects (parts and carriers)
at their GT poses through each view's ``K`` and ``T_cam_world``, with its own materials, lights and world,
drawn per scene from ``--seed`` (``cycles_look.py``): DIMO's parts principled metal, brushed (anisotropic,
stretched marks) or rough; T-LESS's objects grey or coloured plastic; the carriers painted trays of a random
colour; a ground plane under the pile (the largest face of the objects' hull that every camera sees from
behind) with a procedural wood, checker or marble texture from Blender's nodes; no HDRI but a physical sky or a
three-colour gradient; one or two area lights of random size and colour temperature; AgX colour management. The
copy is read by the same loaders, unchanged (the GT files and masks are the source's).

    pip install bpy==4.2.0          # Python 3.11 only; or pip install -e '.[cycles]'
    python scripts/rerender_cycles.py DATA/dimo_test DATA/dimo_test_cycles --split sim --samples 32
    bop-cender run --dataset dimo --data-root DATA/dimo_test_cycles --split sim --workers 2 --score
    python scripts/rerender_cycles.py DATA/tless_test DATA/tless_test_cycles --dataset tless --resume

Writes into DST.partial and renames it DST when every scene is done; a scene is marked done once all its images
are written (each written whole: a temporary file renamed). Interrupted or failed, DST.partial stays: the same
command with ``--resume`` keeps its finished scenes and renders the rest (the same settings are required).
Bad input (a loader's refusal, a skewed camera, a missing image) is found before anything is written.
Deterministic: the same ``--seed`` and ``--samples`` give the same bytes (Cycles' seed is drawn per image, the
look per scene, from ``--seed`` and the scene's key, so a resumed run matches a fresh one; ``--threads`` 1 and 2
gave the same bytes here, denoiser included). T-LESS's loader
makes each image its own group, so each T-LESS image gets its own look.

Seconds per image, measured on the development machine: a 2-core AMD EPYC (Zen 4) SHARED with 4-5 other jobs
(load average 7-8 during the runs), so the wall times are pessimistic and the CPU seconds the steadier figure;
OpenImageDenoise on, all threads, Blender 4.2.0 (results/robustness/cycles_look.md):

    DIMO layout, 320x256 (full size), 3 parts + carrier   --samples 16: 10.4-12.7 s (5.9-6.2 CPU s)
                                                           --samples 32: 16.2 s (9.1 CPU s)
                                                           --samples 64: 32.7 s (20.0 CPU s)
    T-LESS layout, 720x540, 6 objects                      --samples 32: 77 s (40 CPU s)
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
import zlib
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cycles_look import SkewError, blender_camera, draw_look  # noqa: E402

#: The run's state inside DST.partial: its settings and a marker per finished scene; gone once DST is complete.
STATE = ".rerender_cycles"
#: The settings a resumed run must share with the first (they decide the pixels).
SETTINGS = ("src", "dataset", "split", "seed", "samples", "denoise", "limit_scenes")
INSTALL = "pip install bpy==4.2.0 (Blender as a Python module, Python 3.11 only; the project's 'cycles' extra)"


def main(argv: list[str] | None = None) -> int:
    from bop_cender.synth.relook import add_look_arguments

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_look_arguments(ap)
    ap.add_argument("--seed", type=int, default=0, help="draws the looks and Cycles' sampling (default 0)")
    ap.add_argument("--samples", type=int, default=32, help="Cycles samples per pixel (default 32)")
    ap.add_argument("--resume", action="store_true", help="continue DST.partial of an earlier, unfinished run")
    ap.add_argument("--threads", type=int, default=0, help="CPU threads for Cycles (default 0: all cores)")
    ap.add_argument("--no-denoise", action="store_true", help="no OpenImageDenoise (noisier, a little faster)")
    args = ap.parse_args(argv)
    if args.samples < 1 or args.threads < 0 or (args.limit_scenes is not None and args.limit_scenes < 1):
        print("error: --samples and --limit-scenes must be at least 1, --threads at least 0", file=sys.stderr)
        return 2
    try:
        import bpy  # noqa: F401  (Blender as a module: imported once, before any work)
    except Exception as exc:  # ImportError, or a wheel built for another Python
        print(f"error: bpy is not usable here ({exc}); {INSTALL}", file=sys.stderr)
        return 2
    from cycles_scene import CyclesScene, denoiser_available

    from bop_cender.errors import BopCenderError

    if args.dst.exists():
        print(f"error: {args.dst} exists; give a new folder", file=sys.stderr)
        return 2
    tmp = args.dst.with_name(args.dst.name + ".partial")
    if tmp.exists() and not args.resume:
        print(f"error: {tmp} exists (an unfinished run): add --resume to continue it, or delete it", file=sys.stderr)
        return 2
    try:
        dataset, keys, scenes = _checked_input(args)
    except (BopCenderError, SkewError, OSError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    settings = {
        "src": str(args.src.resolve()),
        "dataset": args.dataset,
        "split": args.split,
        "seed": args.seed,
        "samples": args.samples,
        "denoise": not args.no_denoise and denoiser_available(),
        "limit_scenes": args.limit_scenes,
    }
    seconds: list[float] = []
    try:
        problem = _start(args.src, tmp, settings)
        if problem:
            print(f"error: {problem}", file=sys.stderr)
            return 2
        done_dir = tmp / STATE / "done"
        renderer = CyclesScene(dataset.models, args.samples, args.threads, settings["denoise"], tmp / STATE)
        for n, key in enumerate(keys, 1):
            marker = done_dir / _marker_name(key)
            if marker.is_file():
                print(f"cycles: scene {n}/{len(keys)} {key} done in an earlier run", flush=True)
                continue
            scene = scenes[key]
            renderer.set_scene(scene, draw_look(_rng(args.seed, key), args.dataset))
            views = [v for v in scene.views if v.rgb_path is not None]
            for j, view in enumerate(views, 1):
                start = time.perf_counter()
                rgb, _ = renderer.render(view, _cycles_seed(args.seed, key, view.im_id))
                rel = Path(view.rgb_path).relative_to(args.src)
                _write_like(rgb, Path(view.rgb_path), tmp / rel)
                seconds.append(time.perf_counter() - start)
                print(f"cycles: scene {n}/{len(keys)} {key} image {j}/{len(views)} {rel} {seconds[-1]:.1f} s/image",
                      flush=True)  # fmt: skip
            marker.touch()
    except KeyboardInterrupt:
        print(f"\ninterrupted: {tmp} keeps the finished scenes; the same command with --resume continues", file=sys.stderr)  # fmt: skip
        return 130
    except Exception as exc:  # a render or write failure: nothing half-written (whole files), the run resumable
        print(f"error: {type(exc).__name__}: {exc}; {tmp} keeps the finished scenes: the same command with "
              "--resume continues", file=sys.stderr)  # fmt: skip
        return 2
    record = {**settings, "scenes": len(keys), "renderer": f"Blender {_blender_version()} Cycles (CPU)"}
    (tmp / "rerender_cycles.json").write_text(json.dumps(record, indent=1) + "\n")
    shutil.rmtree(tmp / STATE)
    tmp.rename(args.dst)
    mean = f", {np.mean(seconds):.1f} s/image" if seconds else ""
    print(f"wrote {args.dst} ({len(keys)} scenes of split {args.split} path traced by Cycles{mean})")
    return 0


def _checked_input(args: argparse.Namespace):
    """The dataset, the scene keys to render and every one of those scenes, loaded and checked before anything is
    written: the loader's own checks, each view's camera (no skew), its image (there and readable) and each model
    (readable, the size its entry says)."""
    from PIL import Image

    from bop_cender.errors import DatasetError
    from bop_cender.meshes import MeshCache
    from bop_cender.synth.relook import DEFAULT_SPLIT, open_every_image

    args.split = args.split or DEFAULT_SPLIT[args.dataset]
    dataset = open_every_image(args.dataset, args.src, args.split)  # no image of the copy keeps our renderer's look
    keys = dataset.scene_keys[: args.limit_scenes]
    scenes, meshes = {}, MeshCache(dataset.models)
    for key in keys:
        scene = scenes[key] = dataset.scene(key)
        for g in scene.gt:
            meshes.arrays(g.obj_id)
        for view in scene.views:
            try:
                blender_camera(view.K, int(view.width), int(view.height))
            except SkewError as exc:
                raise SkewError(f"{view.source or view.rgb_path}: image {view.im_id}: {exc}") from None
            if view.rgb_path is None:
                continue
            try:
                with Image.open(view.rgb_path) as image:
                    size = image.size
            except OSError as exc:
                raise DatasetError(f"cannot read the image ({exc})", file=view.rgb_path) from None
            if size != (int(view.width), int(view.height)):
                raise DatasetError(f"image is {size[0]}x{size[1]}, the camera says {view.width}x{view.height}",
                                   file=view.rgb_path)  # fmt: skip
    return dataset, keys, scenes


def _start(src: Path, tmp: Path, settings: dict) -> str | None:
    """Make DST.partial (a copy of SRC and the run's settings) or check the one an earlier run left; the problem
    with it, or None."""
    state = tmp / STATE / "settings.json"
    if tmp.exists():
        try:
            earlier = json.loads(state.read_text())
        except (OSError, ValueError):
            earlier = None
        if earlier is None or not earlier.get("copied"):
            if not (tmp / STATE).is_dir():
                return f"{tmp} is not a run of this script; delete it or give another DST"
            shutil.rmtree(tmp)  # our own copy, interrupted before it was complete: copy again
        else:
            for name in SETTINGS:
                if earlier.get(name) != settings[name]:
                    return (f"{state}: {name} was {earlier.get(name)!r}, now {settings[name]!r}; resume with the "
                            "same settings, or delete it")  # fmt: skip
            print(f"cycles: resuming {tmp}", flush=True)
            return None
    (tmp / STATE / "done").mkdir(parents=True)
    state.write_text(json.dumps({**settings, "copied": False}))
    shutil.copytree(src, tmp, dirs_exist_ok=True)
    state.write_text(json.dumps({**settings, "copied": True}))
    return None


def _write_like(rgb: np.ndarray, source: Path, out: Path) -> None:
    """``rgb (H, W, 3) uint8`` to ``out``, in the source image's format and mode, whole or not at all."""
    from PIL import Image

    with Image.open(source) as original:
        fmt, mode = original.format, original.mode
    image = Image.fromarray(rgb)
    if mode != "RGB":
        image = image.convert(mode)
    part = out.with_name(out.name + ".tmp")
    image.save(part, format=fmt, **({"quality": 95} if fmt == "JPEG" else {}))
    os.replace(part, out)


def _rng(seed: int, key: str) -> np.random.Generator:
    """The scene's draws: from the seed and the scene's key (not its position), so a resume draws the same."""
    return np.random.default_rng([seed, zlib.crc32(key.encode())])


def _cycles_seed(seed: int, key: str, im_id: int) -> int:
    """Cycles' sampling seed of one image (a non-negative 31-bit int)."""
    return zlib.crc32(f"{seed}/{key}/{im_id}".encode()) & 0x7FFFFFFF


def _marker_name(key: str) -> str:
    """A file name for a scene key (T-LESS keys hold a '/')."""
    return key.replace("/", "__")


def _blender_version() -> str:
    import bpy

    return bpy.app.version_string


if __name__ == "__main__":
    sys.exit(main())
