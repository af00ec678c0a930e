"""The centre term (``pose/center_term.py``) and the scene judge that adds it to the scene cost (``pose/judge.py``)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).parents[1]))
from method_data import BOX_T_B, pose_config, pose_context, target_parts  # noqa: E402

from bop_cender.pose.center_term import center_term  # noqa: E402
from bop_cender.pose.judge import SceneJudge, placement_cost  # noqa: E402
from bop_cender.pose.types import PlacedObject, PoseTarget  # noqa: E402


def _center_setup(mini, obj_id=3):
    from bop_cender.geometry.sampling import sample_scores

    ds, scene, meshes, maps, cams, dist = mini
    T = target_parts(ds, scene)[obj_id]
    center_map = maps.center[:, 0].numpy()  # (V, H, W): the fixture's one shared centre channel
    c = T[:3, :3] @ ds.models[obj_id].center + T[:3, 3]
    scores = sample_scores(c[None], center_map, cams.Ks, cams.T_cam_world)[0]
    return ds, cams, T, center_map, scores


def test_center_term_is_zero_at_the_detected_centre_and_grows_away_from_it(mini):
    ds, cams, T, center_map, scores = _center_setup(mini)
    shifted = []
    for d in (0.0, 2.0, 5.0, 10.0, 40.0):
        S = T.copy()
        S[:3, 3] += d * np.array([0.6, -0.8, 0.0])
        shifted.append(S)
    w = np.full(len(cams.Ks), 1.0 / len(cams.Ks))
    terms = center_term(np.stack(shifted), ds.models[3].center, scores, center_map, w, cams, 2.0)
    assert terms[0] == pytest.approx(0.0, abs=1e-9)
    assert np.all(np.diff(terms) > 0), terms
    assert terms[-1] <= 2.0 * scores.max() + 1e-9  # at most the weight times the score it can lose
    # a rotation about the centre keeps the centre: no term
    R = T.copy()
    R[:3, :3] = Rotation.from_euler("z", 40, degrees=True).as_matrix() @ T[:3, :3]
    R[:3, 3] = T[:3, :3] @ ds.models[3].center + T[:3, 3] - R[:3, :3] @ ds.models[3].center
    assert center_term(R[None], ds.models[3].center, scores, center_map, w, cams, 2.0)[0] == pytest.approx(0, abs=1e-9)
    assert np.all(center_term(np.stack(shifted), ds.models[3].center, scores, center_map, w, cams, 0.0) == 0)
    assert np.all(center_term(np.stack(shifted), ds.models[3].center, scores, None, w, cams, 2.0) == 0)


def test_the_scene_judge_adds_each_objects_centre_term(mini):
    ds, scene, meshes, maps, cams, dist = mini
    _, _, T, center_map, scores = _center_setup(mini)
    parts = target_parts(ds, scene)
    moved = T.copy()
    moved[:3, 3] += np.array([6.0, -8.0, 0.0])
    placed = [PlacedObject(3, moved, 0.0, 0), PlacedObject(4, parts[4], 0.0, 0)]
    c4 = parts[4][:3, :3] @ ds.models[4].center + parts[4][:3, 3]
    targets = [
        PoseTarget(T[:3, :3] @ ds.models[3].center + T[:3, 3], scores, (3,), center_map),
        PoseTarget(c4, np.ones(len(cams.Ks)), (4,), None),  # no map: no term
    ]
    context = pose_context(mini, pose_config("center_weight=0"))
    plain = placement_cost(placed, context.fine, meshes, BOX_T_B, context.backend)
    assert SceneJudge(context, targets).cost(placed) == plain
    with_term = SceneJudge(pose_context(mini, pose_config("center_weight=1")), targets).cost(placed)
    assert with_term > plain + 0.05
