"""Results rows for a regression fixture that exercise every rule of BOP'24 detection scoring.

Used by the tests, the cross-check against the official toolkit and the speed benchmark
(:mod:`bop_cender.eval.detection` has the rules). :func:`detection_rows` writes, for a
:class:`~bop_cender.synth.regression_fixture.BuiltFixture`:

- per GT instance of a target image (however little of it is visible) 0-3 estimates, each the GT pose moved by one
  of the fixture's perturbations, with scores drawn from a few values (ties within and across images) and some
  negative;
- exact duplicates of some rows; estimates of objects the image does not hold (a model without an instance, and an
  id without a model); rows for images that are not targets and for a scene that does not exist;
- optionally one crowded image with more rows than the cap, whose scores tie across the cut.
"""

from __future__ import annotations

import numpy as np

from bop_cender.results.bop_csv import BopEstimate
from bop_cender.synth.regression_fixture import PERTURBATIONS, BuiltFixture, perturb

#: The few scores estimates draw from: ties everywhere, a negative one, zero.
SCORES = (0.9, 0.75, 0.75, 0.5, 0.5, 0.5, 0.0, -0.25)
#: An object id with no model in any fixture.
UNKNOWN_OBJ_ID = 999
#: A scene id that no fixture has.
MISSING_SCENE_ID = 77


def detection_rows(
    built: BuiltFixture, seed: int = 0, crowded: int = 0, unknown_time: bool = False
) -> list[BopEstimate]:
    """Rows for ``built`` (module docstring). ``crowded``: rows added to the first target image (0: none; above 100
    they cross the toolkit's cap, the last 30 with the score at the cut). ``unknown_time``: one image's rows have
    time -1 (the average time is then unknown)."""
    rng = np.random.default_rng(seed)
    targets = sorted({(t["scene_id"], t["im_id"]) for t in built.targets})
    rows: list[BopEstimate] = []
    for n, key in enumerate(sorted(built.gt)):
        scene, im = key
        time_s = -1.0 if unknown_time and n == 1 else round(0.2 + 0.01 * n, 3)
        if key not in targets:
            _, obj_id, T = built.gt[key][0]
            rows.append(_row(scene, im, obj_id, 0.8, T, time_s))
            continue
        for _gt_id, obj_id, T in built.gt[key]:
            for _ in range(int(rng.integers(0, 4))):
                kind = PERTURBATIONS[int(rng.integers(len(PERTURBATIONS)))]
                score = float(SCORES[int(rng.integers(len(SCORES)))])
                rows.append(_row(scene, im, obj_id, score, perturb(kind, T, built.models[obj_id], rng), time_s))
                if rng.random() < 0.15:  # an exact duplicate
                    rows.append(rows[-1])
        present = {g[1] for g in built.gt[key]}
        absent = [o for o in sorted(built.models) if o not in present]
        T0 = built.gt[key][0][2]
        if absent:
            rows.append(_row(scene, im, absent[0], 0.95, T0, time_s))
        rows.append(_row(scene, im, UNKNOWN_OBJ_ID, 0.6, T0, time_s))
    if crowded:
        scene, im = targets[0]
        time_s = rows[next(i for i, r in enumerate(rows) if (r.scene_id, r.im_id) == (scene, im))].time
        instances = built.gt[(scene, im)]
        for k in range(crowded):
            _gt_id, obj_id, T = instances[k % len(instances)]
            kind = PERTURBATIONS[k % len(PERTURBATIONS)]
            score = 0.3 if k >= crowded - 30 else round(float(rng.uniform(0.3, 1.0)), 2)
            rows.append(_row(scene, im, obj_id, score, perturb(kind, T, built.models[obj_id], rng), time_s))
    rows.append(_row(MISSING_SCENE_ID, 0, next(iter(built.models)), 0.7, np.eye(4), 0.5))
    order = rng.permutation(len(rows))  # file order is not score order
    return [rows[i] for i in order]


def _row(scene: int, im: int, obj_id: int, score: float, T: np.ndarray, time_s: float) -> BopEstimate:
    T = np.asarray(T, dtype=np.float64)
    return BopEstimate(scene, im, obj_id, score, T[:3, :3].copy(), T[:3, 3].copy(), time_s)
