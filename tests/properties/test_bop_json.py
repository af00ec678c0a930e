"""Property tests of the BOP JSON readers: scene_camera / scene_gt / scene_gt_info (one scene folder),
models_info.json, test_targets_bop19.json and the root camera file, each mutated from a valid file that
:mod:`tests.data.bop_builder` wrote."""

from __future__ import annotations

import json
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from bop_cender.data.bop import open_bop
from bop_cender.data.bop_scene import read_scene_folder
from bop_cender.data.models import load_models
from bop_cender.data.targets_file import read_targets
from tests.data.bop_builder import BopSpec, build_bop
from tests.properties.mutate import Case, JsonPath, canon, check, dumps, json_cases, replaced

OBJ_IDS = frozenset({1, 2, 3})
SPEC = BopSpec(n_scenes=2, n_images=3, n_instances=2, pbr_scenes=0, models_dirs=("models",))


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_bop(tmp_path_factory.mktemp("bop") / "bop", SPEC).root


def _tree(path: Path) -> Any:
    return json.loads(path.read_text())


def _semantic(tree: Any, edits: list[tuple[JsonPath, Any, str]]) -> st.SearchStrategy[Case]:
    """Given edits (path, value, what), each making the file invalid."""
    return st.sampled_from(edits).map(lambda e: Case(dumps(replaced(tree, e[0], e[1])), "invalid", e[2]))


def _rotations(tree: Any, paths: list[JsonPath]) -> list[tuple[JsonPath, Any, str]]:
    """Non-orthonormal rotations at ``paths``: scaled, a reflection, a random matrix, a zero matrix."""
    rng = np.random.default_rng(0)
    out = []
    for p in paths:
        R = np.asarray(_get(tree, p), dtype=float)
        out += [
            (p, (R * 1.1).tolist(), f"{p} scaled by 1.1"),
            (p, (-R).tolist(), f"{p} a reflection (det -1)"),
            (p, rng.normal(size=9).tolist(), f"{p} a random matrix"),
            (p, [0.0] * 9, f"{p} zeros"),
        ]
    return out


def _get(tree: Any, path: JsonPath) -> Any:
    for k in path:
        tree = tree[k]
    return tree


# ---------------------------------------------------------------------------------------------- one scene folder

SCENE_FILES = ("scene_camera.json", "scene_gt.json", "scene_gt_info.json")


def _scene_strict(name: str) -> Callable[[JsonPath, str], bool]:
    def strict(path: JsonPath, op: str) -> bool:
        if len(path) == 1:  # an image entry: its id in every file, an object / a list
            return True
        if name == "scene_camera.json":
            key = path[1]
            if key == "depth_scale":
                return len(path) > 2 or op == "bad"  # absent: the root camera file's default
            return key in ("cam_K", "cam_R_w2c", "cam_t_w2c")  # (absent R and t together: no world pose)
        if name == "scene_gt.json":
            return True  # every key required; an annotation less: scene_gt_info's list no longer matches
        if len(path) == 2:
            return True  # one entry per annotation
        return path[2] == "visib_fract" and len(path) == 3

    return strict


def _scene_cases(name: str, tree: Any) -> st.SearchStrategy[Case]:
    ims = sorted(tree)
    if name == "scene_camera.json":
        im = ims[0]
        K = tree[im]["cam_K"]
        edits = [
            ((im, "cam_K"), [-K[0], *K[1:]], "fx negative"),
            ((im, "cam_K"), [0.0, *K[1:]], "fx zero"),
            ((im, "cam_K"), [*K[:6], 0.0, 0.0, 0.0], "last row of K zeros"),
            ((im, "depth_scale"), 0, "depth_scale zero"),
            ((im, "depth_scale"), -0.1, "depth_scale negative"),
            ((im, "cam_K"), K[:8], "cam_K 8 numbers"),
            ((im, "cam_t_w2c"), [1.0, 2.0], "cam_t_w2c 2 numbers"),
            ((im, "cam_K"), [K[:3], K[3:6], K[6:]], "cam_K as 3x3 nested"),
            *_rotations(tree, [(i, "cam_R_w2c") for i in ims]),
        ]
    elif name == "scene_gt.json":
        edits = [
            ((ims[0], 0, "obj_id"), 999, "unknown obj_id 999"),
            ((ims[-1], 1, "obj_id"), 0, "unknown obj_id 0"),
            ((ims[0], 0, "obj_id"), 1.5, "obj_id 1.5"),
            ((ims[0], 0, "cam_t_m2c"), [1.0, 2.0, 3.0, 4.0], "cam_t_m2c 4 numbers"),
            *_rotations(tree, [(i, 0, "cam_R_m2c") for i in ims]),
        ]
    else:
        edits = [((ims[0], 0, "visib_fract"), v, f"visib_fract {v}") for v in (1.5, -0.2, 2, 1e308)]
        edits.append(((ims[0],), tree[ims[0]] + tree[ims[0]][:1], "one entry too many"))
    return json_cases(tree, _scene_strict(name), _semantic(tree, edits))


def _scene_test(name: str) -> Callable[..., None]:
    def run(built: Path, data: st.DataObject) -> None:
        scene = built / SPEC.split_folder / "000001"
        tree = _tree(scene / name)
        case = data.draw(_scene_cases(name, tree), label="case")
        with tempfile.TemporaryDirectory() as tmp:
            root = Path(tmp)
            for f in SCENE_FILES:
                shutil.copy(scene / f, root / f)
            reference = canon(read_scene_folder(root, OBJ_IDS), root)
            (root / name).write_bytes(case.data)
            check(case, lambda: read_scene_folder(root, OBJ_IDS), root, name, reference)

    return given(data=st.data())(run)


test_scene_camera_json = _scene_test("scene_camera.json")
test_scene_gt_json = _scene_test("scene_gt.json")
test_scene_gt_info_json = _scene_test("scene_gt_info.json")


# ---------------------------------------------------------------------------------------------- models_info.json

_INFO_KEYS = ("diameter", "min_x", "min_y", "min_z", "size_x", "size_y", "size_z")


def _models_strict(path: JsonPath, op: str) -> bool:
    if len(path) == 1:
        return op != "delete"  # a model less is a smaller valid dataset
    key = path[1]
    if key in _INFO_KEYS:
        return True
    if key in ("symmetries_discrete", "symmetries_continuous"):
        if len(path) == 2:
            return False  # absent, null or empty: no symmetry (as the toolkit reads it)
        if len(path) == 3:
            return op != "delete"  # one symmetry less is valid
        if key == "symmetries_continuous" and len(path) == 4 and path[3] == "offset":
            return op == "bad"  # absent (deleted, renamed): offset 0
        return True
    return False


@given(data=st.data())
def test_models_info_json(built: Path, data: st.DataObject) -> None:
    tree = _tree(built / "models" / "models_info.json")
    edits = [
        (("1", "diameter"), 0, "diameter 0"),
        (("2", "diameter"), -10.0, "diameter negative"),
        (("3", "size_x"), -1.0, "size_x negative"),
        (("1", "symmetries_continuous", 0, "axis"), [0, 0, 0], "zero symmetry axis"),
        (("1", "symmetries_continuous"), True, "symmetries_continuous true"),
        (("2", "symmetries_discrete"), 1.5, "symmetries_discrete a number"),
        (("2", "symmetries_discrete"), "x", "symmetries_discrete a string"),
        (("2", "symmetries_discrete", 0), [0.0] * 16, "a discrete symmetry of zeros"),
        (("2", "symmetries_discrete", 0), [2.0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1], "a scaling symmetry"),
        (("2", "symmetries_discrete", 0), [1.0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0], "last row not 0 0 0 1"),
    ]
    case = data.draw(json_cases(tree, _models_strict, _semantic(tree, edits)), label="case")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        shutil.copytree(built / "models", root / "models")
        reference = canon(load_models(root / "models"), root)
        (root / "models" / "models_info.json").write_bytes(case.data)
        check(case, lambda: load_models(root / "models"), root, "models_info.json", reference)


# ---------------------------------------------------------------------------------------------- targets, camera file


def _targets_strict(path: JsonPath, op: str) -> bool:
    return len(path) >= 2 or op != "delete"  # one target less is valid; every key is required


@given(data=st.data())
def test_targets_file_reader(built: Path, data: st.DataObject) -> None:
    """``read_targets`` alone (what the scorer reads)."""
    tree = _tree(built / "test_targets_bop19.json")
    edits = [((0, "inst_count"), 0, "inst_count 0"), ((0, "im_id"), -1, "im_id -1"), ((1, "obj_id"), 2.0, "obj_id 2.0")]
    case = data.draw(json_cases(tree, _targets_strict, _semantic(tree, edits)), label="case")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        path = root / "test_targets_bop19.json"
        path.write_bytes((built / "test_targets_bop19.json").read_bytes())
        reference = canon(read_targets(path), root)
        path.write_bytes(case.data)
        check(case, lambda: read_targets(path), root, path.name, reference)


def _open_all(root: Path) -> tuple:
    ds = open_bop(root, "test")
    return ds.scene_keys, ds.models, ds.image_size, ds.selection, ds.bop19_targets()


def _camera_strict(path: JsonPath, op: str) -> bool:
    return path[0] in ("width", "height") or (path[0] == "depth_scale" and op == "bad")


@pytest.mark.parametrize("name", ["test_targets_bop19.json", "camera_primesense.json"])
@given(data=st.data())
def test_open_bop_root_files(built: Path, name: str, data: st.DataObject) -> None:
    """The targets file and the root camera file as ``open_bop`` reads them (ids checked against the data)."""
    tree = _tree(built / name)
    if name == "test_targets_bop19.json":
        strict = _targets_strict
        edits = [
            ((0, "scene_id"), 7, "a scene with no folder"),
            ((0, "im_id"), 99, "an image not in scene_camera.json"),
            ((0, "obj_id"), 42, "an object not in the models"),
            ((0, "inst_count"), 0, "inst_count 0"),
        ]
        extra = [_semantic(tree, edits), st.just(Case(b"[]\n", "invalid", "no targets"))]
    else:
        strict = _camera_strict
        extra = [_semantic(tree, [(("width",), 0, "width 0"), (("height",), -24, "height negative"),
                                  (("depth_scale",), 0, "depth_scale 0")])]  # fmt: skip
    case = data.draw(json_cases(tree, strict, *extra), label="case")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "bop"
        shutil.copytree(built, root)
        reference = canon(_open_all(root), root)
        (root / name).write_bytes(case.data)
        check(case, lambda: _open_all(root), root, name, reference)
