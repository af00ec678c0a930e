"""The per-scene figure's verdicts (which poses are right) and crops (where the objects are)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from bop_cender.data.types import ObjectModel
from bop_cender.geometry.symmetry import ContinuousSymmetry
from bop_cender.report.scene_figure import crop_box, figure_title, judge_estimates, outline


def _pose(rotvec=(0.0, 0.0, 0.0), t=(0.0, 0.0, 0.0)) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


@pytest.fixture()
def models(tmp_path: Path) -> dict[int, ObjectModel]:
    """Obj 1: a 100 x 40 x 20 mm box (no symmetry declared); obj 2: a cylinder symmetric about z."""
    box = tmp_path / "obj_000001.ply"
    box.write_bytes(trimesh.exchange.ply.export_ply(trimesh.creation.box(extents=(100.0, 40.0, 20.0))))
    cyl = tmp_path / "obj_000002.ply"
    cyl.write_bytes(trimesh.exchange.ply.export_ply(trimesh.creation.cylinder(radius=20.0, height=60.0, sections=32)))
    return {
        1: ObjectModel(1, box, float(np.sqrt(100**2 + 40**2 + 20**2)), np.array([-50.0, -20, -10]), np.array([100.0, 40, 20])),
        2: ObjectModel(2, cyl, float(np.sqrt(40**2 + 60**2)), np.array([-20.0, -20, -30]), np.array([40.0, 40, 60]),
                       symmetries_continuous=[ContinuousSymmetry((0.0, 0.0, 1.0))]),
    }  # fmt: skip


def test_verdicts_match_one_to_one_by_mssd_under_five_percent_of_the_diameter(models) -> None:
    gt = [(1, _pose(t=(0, 0, 500))), (1, _pose(t=(200, 0, 500))), (2, _pose(t=(0, 200, 500)))]
    estimates = [
        (1, _pose(t=(201, 0, 500))),  # 1 mm from the second box: right
        (1, _pose(t=(1, 0, 500))),  # 1 mm from the first: right
        (1, _pose(t=(0.5, 0, 500))),  # a duplicate of the first box, closer: it takes the box
        (2, _pose((0.0, 0.0, 2.0), (0, 200, 500))),  # the cylinder turned about its axis: right (symmetry)
        (
            1,
            _pose((0.0, 0.0, 0.5), (0, 200, 500)),
        ),  # a box where the cylinder is: wrong (the nearest box is 200 mm away)
    ]
    v = judge_estimates(estimates, gt, models)
    # the duplicate at 0.5 mm takes the first box; the estimate at 1 mm finds no free box of its id
    assert v.estimate_right == (True, False, True, True, False)
    assert v.gt_found == (True, True, True)
    assert v.errors_mm[0] == pytest.approx(1.0) and v.errors_mm[2] == pytest.approx(0.5)
    assert v.errors_mm[3] < 0.2  # the symmetric pose costs only the sampling of its continuous symmetry (as scored)
    assert v.errors_mm[4] > 150.0


def test_a_pose_just_over_five_percent_is_wrong_and_leaves_its_part_missed(models) -> None:
    d = models[1].diameter
    gt = [(1, _pose(t=(0, 0, 500)))]
    assert judge_estimates([(1, _pose(t=(0.049 * d, 0, 500)))], gt, models).estimate_right == (True,)
    late = judge_estimates([(1, _pose(t=(0.051 * d, 0, 500)))], gt, models)
    assert late.estimate_right == (False,) and late.gt_found == (False,)
    assert late.errors_mm[0] == pytest.approx(0.051 * d)
    # the box turned by 180 degrees about z is another pose for an unsymmetric model: wrong
    assert judge_estimates([(1, _pose((0, 0, np.pi), (0, 0, 500)))], gt, models).estimate_right == (False,)
    other_id = judge_estimates([(2, _pose(t=(0, 0, 500)))], gt, models)  # no GT part of its id
    assert other_id.estimate_right == (False,) and other_id.errors_mm == (np.inf,)
    none = judge_estimates([], gt, models)
    assert none.estimate_right == () and none.gt_found == (False,)


def test_crop_box_holds_the_objects_at_the_image_aspect_ratio() -> None:
    H, W = 540, 720
    mask = np.zeros((H, W), dtype=bool)
    mask[300:340, 500:560] = True
    top, left, h, w = crop_box(mask, np.array([[480.0, 290.0], [np.nan, 3.0], [-50.0, 10.0], [900.0, 20.0]]))
    assert top >= 0 and top + h <= H and left >= 0 and left + w <= W
    assert top <= 290 and top + h >= 340 and left <= 480 and left + w >= 560  # the mask and the point inside
    assert top > 10 and left > 0  # the points outside the image and the NaN one are left out
    assert h / w == pytest.approx(H / W, rel=0.02) and h >= 0.3 * H
    assert crop_box(np.zeros((H, W), dtype=bool), np.zeros((0, 2))) == (0, 0, H, W)  # nothing: all of it


def test_crop_box_moves_inside_the_image_and_never_exceeds_it() -> None:
    mask = np.zeros((100, 200), dtype=bool)
    mask[0:5, 190:200] = True  # a corner
    top, left, h, w = crop_box(mask, np.zeros((0, 2)))
    assert (top, left + w) == (0, 200) and h >= 30
    mask[:] = True
    assert crop_box(mask, np.zeros((0, 2))) == (0, 0, 100, 200)


def test_outline_is_the_mask_pixels_next_to_the_outside() -> None:
    mask = np.zeros((6, 7), dtype=bool)
    mask[1:5, 1:6] = True
    edge = outline(mask)
    assert edge[1, 1:6].all() and edge[4, 1:6].all() and edge[1:5, 1].all() and edge[1:5, 5].all()
    assert not edge[2:4, 2:5].any() and not edge[~mask].any()
    full = np.ones((3, 3), dtype=bool)
    assert outline(full).sum() == 8  # the image's border counts as outside


def test_the_title_of_a_narrow_figure_wraps_and_keeps_each_time_whole() -> None:
    """One- and two-view figures cut their one-line title at both sides."""
    timings = {"heatmaps": 2.0, "centers": 0.04, "poses": 12.0}
    head = "scene 000000_00: 4 estimated, 4 GT, 3 right (MSSD < 5% of the diameter)"
    narrow = figure_title(head, timings, 2.2).splitlines()
    assert len(narrow) > 2 and all(len(line) <= 28 for line in narrow)
    assert "poses\u00a012.0\u00a0s" in narrow[-1]  # never "12.0" on one line and "s" on the next
    assert figure_title(head, timings, 15.4).count("\n") == 0  # seven views: one line
