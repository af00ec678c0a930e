"""Cross-check: DIMO's own published loader reads our DIMO-layout data, with the same poses as ours.

Usage:
    python scripts/crosscheck_dimo_loader.py DIMO_LOADER_PY DATASET_ROOT

DIMO_LOADER_PY is ``scripts/dimo_loader.py`` of the DIMO website repository (pderoovere/dimo,
branch gh-pages), kept OUTSIDE this repository. The script loads every camera folder with it and
with ``bop_cender.data.dimo.open_dimo`` (no selection) and compares cameras and object poses.
Exits 0 with a message when the loader file is not given or absent: it is never a dependency.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

import numpy as np


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dimo_loader", nargs="?", help="DIMO's scripts/dimo_loader.py (outside this repository)")
    ap.add_argument("dataset_root", nargs="?", help="a DIMO-layout dataset root")
    args = ap.parse_args(argv)
    if args.dataset_root is None or not Path(args.dimo_loader).is_file():
        print("DIMO's dimo_loader.py not given or not found: cross-check skipped (see --help).")
        return 0
    spec = importlib.util.spec_from_file_location("dimo_loader", args.dimo_loader)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    root = Path(args.dataset_root)
    from bop_cender.data.dimo import DimoSelection, open_dimo

    cameras = sorted(p.name for p in root.iterdir() if p.is_dir() and p.name.startswith(("real_", "sim_")))
    official = module.DimoLoader().load(root, cameras=cameras)
    n_images = n_objects = 0
    worst_cam = worst_obj = 0.0
    for camera in cameras:
        split = "real" if camera.startswith("real_") else None
        splits = [split] if split else ["sim", "train"]
        ours = {}
        for sp in splits:
            everything = DimoSelection.everything(camera=camera.split("_", 1)[1])
            try:
                ds = open_dimo(root, sp, everything)
            except Exception as e:  # a split with no folders in this dataset
                print(f"  ({camera} {sp}: {e.__class__.__name__})")
                continue
            for scene in ds.scenes():
                ours[scene.scene_id] = scene
        for scene_off in official[camera]:
            scene = ours[scene_off["id"]]
            for img in scene_off["images"]:
                view = scene.view(img["id"])
                worst_cam = max(
                    worst_cam, float(np.abs(np.linalg.inv(img["camera"]["cam_2world"]) - view.T_cam_world).max())
                )
                by_gt = {g.gt_ids[img["id"]]: g for g in scene.gt}
                for k, obj in enumerate(img["objects"]):
                    g = by_gt[k]
                    assert obj["id"] == g.obj_id, (scene.scene_id, img["id"], k)
                    worst_obj = max(worst_obj, float(np.abs(obj["model_2world"] - g.T_world_model).max()))
                    T_cam_model = view.T_cam_world @ g.T_world_model
                    worst_obj = max(worst_obj, float(np.abs(obj["model_2cam"] - T_cam_model).max()))
                    n_objects += 1
                n_images += 1
    print(f"official DIMO loader read {n_images} images, {n_objects} object poses in {cameras}")
    print(f"max |difference| vs bop-cender: cameras {worst_cam:.2e}, object poses {worst_obj:.2e} (mm / unitless)")
    ok = n_images > 0 and worst_cam < 1e-6 and worst_obj < 1e-6
    print("OK" if ok else "MISMATCH")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
