"""Where a run's poses go wrong, part by part, in the world frame (a multi-view scene places each part once).

For every target part of every scene of a DIMO-layout split, the estimate of the same object id nearest
to it by MSSD (symmetry-aware, ``bop_cender.eval.pose_errors.mssd``) in the scene's first image, moved to
the world frame with that view's ``T_cam_world``. Each part falls in one class:

- ``< 5 %``: MSSD under 5 % of the diameter (what AR_MSSD<5% counts);
- ``5-10 %``, ``10-25 %``: close, a refinement or a symmetric-looking turn away;
- ``wrong pose``: an estimate of its id lies within 10 mm (centre to centre), its pose is off;
- ``wrong id``: no estimate of its id near it, but one of another id (a similar part placed there);
- ``no estimate``: nothing within 10 mm (stage 2 missed its centre, or the centre was used elsewhere).

With ``--list`` each part outside ``< 5 %`` is printed with its mean visible fraction over the views (rendered
for the whole pile, carriers included),
the centre error, the rotation error (degrees, before symmetries) and MSSD / diameter:

    python scripts/diagnose_poses.py RESULTS.csv --data-root DATA/dimo_test --split sim [--list]

The classes tell stage 2's misses from stage 3's, and what would help (a wider search, another judge,
a longer polish). The mean visible fraction says whether the misses are the buried parts.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter, defaultdict

import numpy as np

from bop_cender.data.registry import DatasetRequest
from bop_cender.data.scene_ids import scene_folder_to_int
from bop_cender.datasets import open_with_demo
from bop_cender.errors import BopCenderError
from bop_cender.eval.pose_errors import hull_vertices, mssd
from bop_cender.meshes import MeshCache
from bop_cender.results.bop_csv import read_bop_results
from bop_cender.visibility import pile_visibility

CLASSES = ("< 5 %", "5-10 %", "10-25 %", "wrong pose", "wrong id", "no estimate")
NEAR_MM = 10.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("results")
    ap.add_argument("--data-root", default=None)
    ap.add_argument("--split", default="sim")
    ap.add_argument("--list", action="store_true", help="print every part outside the 5 %% class")
    args = ap.parse_args()
    ds = open_with_demo(DatasetRequest("dimo", args.data_root, args.split))
    rows = read_bop_results(args.results)
    by_image: dict[tuple[int, int], list] = defaultdict(list)
    for r in rows:
        by_image[(r.scene_id, r.im_id)].append(r)
    meshes = MeshCache(ds.models)
    hulls = {i: hull_vertices(np.asarray(m.mesh.vertices)) for i, m in ds.models.items() if m.is_target}
    counts: Counter[str] = Counter()
    visib: dict[str, list[float]] = defaultdict(list)
    per_obj: dict[int, Counter[str]] = defaultdict(Counter)
    scenes = 0
    for key in ds.scene_keys:
        scene = ds.scene(key)
        view = scene.views[0]
        ests = by_image.get((scene_folder_to_int(scene.scene_id), view.im_id))
        if ests is None:
            continue
        scenes += 1
        T_wc = np.linalg.inv(view.T_cam_world)
        T_we = [T_wc @ e.T_cam_model for e in ests]
        centre_e = np.array(
            [T[:3, :3] @ ds.models[e.obj_id].center + T[:3, 3] for T, e in zip(T_we, ests, strict=True)]
        )
        gts = [g for g in scene.gt if g.obj_id in ds.models]  # carriers too: they hide parts
        Ks = np.stack([w.K for w in scene.views])
        T_cm = np.einsum("vij,mjk->vmik", np.stack([w.T_cam_world for w in scene.views]),
                         np.stack([g.T_world_model for g in gts]))  # fmt: skip
        fract = pile_visibility(meshes.many([g.obj_id for g in gts]), T_cm, Ks, view.height, view.width).fract
        for m, g in enumerate(gts):
            model = ds.models[g.obj_id]
            if not model.is_target:
                continue
            cls, detail = _classify(g, model, ests, T_we, centre_e, hulls[g.obj_id])
            v = float(fract[:, m].mean())
            counts[cls] += 1
            visib[cls].append(v)
            per_obj[g.obj_id][cls] += 1
            if args.list and cls != CLASSES[0]:
                print(f"  {key} obj {g.obj_id}: {cls:11s} visible {v:.2f} {detail}")
    if scenes == 0:
        sys.exit(f"error: {args.results} has no rows for the first image of any scene of {ds.root}, split {args.split}")
    total = sum(counts.values())
    print(f"{args.results}: {scenes} scenes, {total} target parts ({ds.root}, split {args.split})")
    print(f"{'class':12s} {'parts':>5s} {'share':>6s} {'mean visible':>12s}")
    for cls in CLASSES:
        share = counts[cls] / max(total, 1)
        vis = np.nanmean(visib[cls]) if visib[cls] else float("nan")
        print(f"{cls:12s} {counts[cls]:5d} {share:6.3f} {vis:12.2f}")
    print("per object id: " + "; ".join(
        f"{o}: {c[CLASSES[0]]}/{sum(c.values())}" for o, c in sorted(per_obj.items())))  # fmt: skip


def _classify(g, model, ests, T_we, centre_e, hull) -> tuple[str, str]:
    """The class of GT part ``g`` and a line of detail (centre and rotation error, MSSD / diameter)."""
    centre_g = g.T_world_model[:3, :3] @ model.center + g.T_world_model[:3, 3]
    same = [i for i, e in enumerate(ests) if e.obj_id == g.obj_id]
    sym_R, sym_t = model.symmetry_transforms()
    if same:
        R_e = np.stack([T_we[i][:3, :3] for i in same])
        t_e = np.stack([T_we[i][:3, 3] for i in same])
        err = mssd(R_e, t_e, g.T_world_model[:3, :3], g.T_world_model[:3, 3], hull, sym_R, sym_t)
        k = int(np.argmin(err))
        rel = err[k] / model.diameter
        i = same[k]
        d_centre = float(np.linalg.norm(centre_e[i] - centre_g))
        cos = (np.trace(T_we[i][:3, :3].T @ g.T_world_model[:3, :3]) - 1) / 2
        detail = f"centre {d_centre:6.1f} mm, rotation {np.degrees(np.arccos(np.clip(cos, -1, 1))):6.1f} deg, MSSD {rel:.3f} d"
        for limit, cls in ((0.05, CLASSES[0]), (0.10, CLASSES[1]), (0.25, CLASSES[2])):
            if rel < limit:
                return cls, detail
        near_same = np.linalg.norm(centre_e[same] - centre_g, axis=1).min()
        if near_same < NEAR_MM:
            return CLASSES[3], detail
    d_any = np.linalg.norm(centre_e - centre_g, axis=1) if len(centre_e) else np.array([np.inf])
    j = int(np.argmin(d_any))
    if d_any[j] < NEAR_MM and ests[j].obj_id != g.obj_id:
        return CLASSES[4], f"obj {ests[j].obj_id} placed {d_any[j]:.1f} mm from its centre"
    return CLASSES[5], f"nearest estimate {d_any[j]:.1f} mm"


if __name__ == "__main__":
    try:
        main()
    except BopCenderError as e:
        sys.exit(f"error: {e}")
