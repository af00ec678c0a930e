"""Stage 2 alone on oracle heatmaps: how many GT centres the 3D centres find, for several d_c / d_o.

For each scene of a DIMO-layout split, the oracle center heatmaps (rendered from the GT) go through
:func:`bop_cender.centers.detect_centers` with the known object count; a GT centre counts as found
when a detected centre lies within 5 mm of it. Prints one line per setting:

    python scripts/eval_centers.py --data-root DATA --split sim --scenes 24
"""

from __future__ import annotations

import argparse

import numpy as np

from bop_cender.centers import CenterConfig, detect_centers
from bop_cender.data.registry import DatasetRequest
from bop_cender.datasets import open_with_demo
from bop_cender.meshes import MeshCache
from bop_cender.method import CenDerNetConfig
from bop_cender.net.oracle import OraclePredictor

SETTINGS = {
    "paper d_c 30, d_o 30": CenterConfig.paper(),
    "ours d_c 10, d_o 10": CenterConfig(),
    "d_c 10, d_o 15": CenterConfig(d_c=10.0, d_o=15.0),
    "d_c 15, d_o 15": CenterConfig(d_c=15.0, d_o=15.0),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data-root", default=None)
    ap.add_argument("--split", default="sim")
    ap.add_argument("--scenes", type=int, default=None)
    args = ap.parse_args()
    ds = open_with_demo(DatasetRequest("dimo", args.data_root, args.split))  # no data root: the demo, silently
    config = CenDerNetConfig.for_dataset("dimo")
    meshes = MeshCache(ds.models)
    oracle = OraclePredictor(ds.models, meshes, config.targets)
    found = dict.fromkeys(SETTINGS, 0)
    errors: dict[str, list[float]] = {k: [] for k in SETTINGS}
    total = 0
    for key in ds.scene_keys[: args.scenes]:
        scene = ds.scene(key)
        maps = oracle.predict(scene).center.numpy()
        Ks = np.stack([v.K for v in scene.views])
        T_cw = np.stack([v.T_cam_world for v in scene.views])
        gt = np.array([g.T_world_model[:3, :3] @ ds.models[g.obj_id].center + g.T_world_model[:3, 3]
                       for g in scene.gt if ds.models[g.obj_id].is_target]).reshape(-1, 3)  # fmt: skip
        total += len(gt)
        for name, setting in SETTINGS.items():
            centers = detect_centers(maps, Ks, T_cw, setting, None, {0: len(gt)})
            P = np.array([c.position for c in centers]).reshape(-1, 3)
            if len(P) == 0 or len(gt) == 0:
                continue
            nearest = np.linalg.norm(gt[:, None] - P[None], axis=-1).min(1)
            found[name] += int((nearest < 5.0).sum())
            errors[name] += nearest[nearest < 5.0].tolist()
    print(f"{len(ds.scene_keys[: args.scenes])} scenes, {total} GT centres ({ds.root}, split {args.split})")
    for name in SETTINGS:
        med = np.median(errors[name]) if errors[name] else float("nan")
        print(
            f"{name}: {found[name]}/{total} found within 5 mm ({found[name] / max(total, 1):.3f}); median error {med:.2f} mm"
        )


if __name__ == "__main__":
    main()
