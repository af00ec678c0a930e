"""Cross-check: the official BOP toolkit's readers read our T-LESS-layout data unchanged.

Usage:
    python scripts/crosscheck_tless_layout.py TOOLKIT_DIR DATASET_ROOT

TOOLKIT_DIR holds ``bop_toolkit_lib`` (thodan/bop_toolkit, kept OUTSIDE this repository). Uses its
``dataset_params.get_split_params``/``get_model_params`` for ``tless`` (so folder and file names
must be exactly what it expects), ``inout.load_scene_camera``, ``load_scene_gt``, ``load_json``,
``load_depth`` and ``load_ply`` on every scene, image and model, and compares with our loader.
Exits 2 with a message when the toolkit is not importable: it is never a dependency.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("toolkit_dir", help="folder holding bop_toolkit_lib (outside this repository)")
    ap.add_argument("dataset_root", help="a T-LESS-layout dataset root")
    args = ap.parse_args(argv)
    from bop_toolkit_adapters.runtime import ToolkitUnavailable, import_toolkit

    try:
        import_toolkit(args.toolkit_dir)
    except ToolkitUnavailable as e:
        print(f"cross-check not run: {e}", file=sys.stderr)
        return 2
    from bop_toolkit_lib import dataset_params, inout

    root = Path(args.dataset_root)
    from bop_cender.data.bop_io import load_depth
    from bop_cender.data.tless import open_tless

    sp = dataset_params.get_split_params(str(root.parent), root.name, "test")
    mp = dataset_params.get_model_params(str(root.parent), root.name, "eval")
    ours = open_tless(root, "test", n_views=1)
    worst = 0.0
    n_img = n_gt = 0
    for obj_id, model in ours.eval_models.items():
        ply = inout.load_ply(mp["model_tpath"].format(obj_id=obj_id))
        worst = max(worst, float(np.abs(ply["pts"] - model.mesh.vertices).max()))
    targets = inout.load_json(str(root / "test_targets_bop19.json"))
    for scene in ours.scenes():
        sid = int(scene.scene_id)
        cams = inout.load_scene_camera(sp["scene_camera_tpath"].format(scene_id=sid))
        gts = inout.load_scene_gt(sp["scene_gt_tpath"].format(scene_id=sid))
        infos = inout.load_json(sp["scene_gt_info_tpath"].format(scene_id=sid), keys_to_int=True)
        for view in scene.views:
            c = cams[view.im_id]
            worst = max(worst, float(np.abs(c["cam_K"] - view.K).max()))
            worst = max(worst, float(np.abs(c["cam_R_w2c"] - view.T_cam_world[:3, :3]).max()))
            worst = max(worst, float(np.abs(c["cam_t_w2c"].ravel() - view.T_cam_world[:3, 3]).max()))
            d_tk = inout.load_depth(sp["depth_tpath"].format(scene_id=sid, im_id=view.im_id)) * c["depth_scale"]
            worst = max(worst, float(np.abs(d_tk - load_depth(view.depth_path, view.depth_scale)).max()))
            assert len(infos[view.im_id]) == len(gts[view.im_id])
            for g in scene.gt:
                e = gts[view.im_id][g.gt_ids[view.im_id]]
                T = view.T_cam_world @ g.T_world_model
                worst = max(
                    worst,
                    float(np.abs(e["cam_R_m2c"] - T[:3, :3]).max()),
                    float(np.abs(e["cam_t_m2c"].ravel() - T[:3, 3]).max()),
                )
                n_gt += 1
            n_img += 1
    print(
        f"official toolkit read {len(ours.eval_models)} eval models, {n_img} images, {n_gt} GT poses, {len(targets)} targets"
    )
    print(f"split folder {sp['split_path']}, image size {sp['im_size']}")
    print(f"max |difference| vs bop-cender: {worst:.2e}")
    ok = n_img > 0 and worst < 1e-4
    print("OK" if ok else "MISMATCH")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
