"""Property tests of DIMO's scene files (scene_camera with c2w and w2c poses, scene_gt, scene_gt_world,
scene_info) as ``load_dimo_scene`` and ``list_dimo_scenes`` read them, mutated from a folder that
:mod:`tests.data.dimo_builder` wrote."""

from __future__ import annotations

import json
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from bop_cender.data.dimo import CARRIER_MIN_ID, DimoSelection, list_dimo_scenes, load_dimo_scene
from bop_cender.data.models import load_models
from tests.data.dimo_builder import SceneSpec, build_dimo
from tests.properties.mutate import Case, JsonPath, canon, check, dumps, json_cases, replaced

FILES = ("scene_camera.json", "scene_gt.json", "scene_gt_world.json", "scene_info.json")


@pytest.fixture(scope="module")
def dimo_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("dimo") / "dimo"
    build_dimo(root, [SceneSpec("000000", viewpoints=(0, 2, 4))])
    return root


def _strict(name: str) -> Callable[[JsonPath, str], bool]:
    def strict(path: JsonPath, op: str) -> bool:
        if name == "scene_info.json" and len(path) == 2 and path[1] == "light":
            return op == "bad"  # optional, but an integer where present
        if name == "scene_info.json" and len(path) >= 2:
            return path[1] in ("carrier", "parts", "viewpoint")
        return True  # every other key of these files is required, every list has a fixed length

    return strict


def _bad_rotations(tree: object, paths: list[JsonPath]) -> list[Case]:
    rng = np.random.default_rng(1)
    out = []
    for p in paths:
        R = np.asarray(_get(tree, p), dtype=float)
        for how, bad in (("scaled", R * 1.1), ("reflection", -R), ("random", rng.normal(size=9)), ("zeros", 0 * R)):
            out.append(Case(dumps(replaced(tree, p, bad.tolist())), "invalid", f"{p} {how}"))
    return out


def _get(tree: object, path: JsonPath) -> object:
    for k in path:
        tree = tree[k]  # type: ignore[index]
    return tree


def _semantic(name: str, tree: object) -> st.SearchStrategy[Case]:
    if name == "scene_camera.json":
        t = _get(tree, ("0", "cam_t_w2c"))
        cases = _bad_rotations(tree, [("0", "cam_R_c2w"), ("1", "cam_R_w2c")])
        cases.append(
            Case(dumps(replaced(tree, ("0", "cam_t_w2c"), [t[0] + 100, *t[1:]])), "invalid", "w2c != inv(c2w)")
        )
        cases.append(Case(dumps(replaced(tree, ("2", "cam_K", 0), -1.0)), "invalid", "fx negative"))
    elif name == "scene_gt.json":
        cases = _bad_rotations(tree, [("0", 0, "cam_R_m2c")])
        t = _get(tree, ("1", 1, "cam_t_m2c"))
        cases.append(Case(dumps(replaced(tree, ("1", 1, "cam_t_m2c"), [t[0] + 50, *t[1:]])), "invalid", "t off by 50"))
        cases.append(Case(dumps(replaced(tree, ("0", 0, "obj_id"), 2)), "invalid", "obj_id not the world's"))
        cases.append(Case(dumps(replaced(tree, ("0", 0, "obj_id"), "1")), "invalid", "obj_id a string"))
    elif name == "scene_gt_world.json":
        cases = _bad_rotations(tree, [(1, "cam_R_m2w")])
        cases.append(Case(dumps(replaced(tree, (0, "obj_id"), 999)), "invalid", "unknown obj_id"))
    else:
        cases = [Case(dumps(replaced(tree, ("1", "carrier"), "two")), "invalid", "carrier 'two'"),
                 Case(dumps(replaced(tree, ("1", "viewpoint"), 2.5)), "invalid", "viewpoint 2.5")]  # fmt: skip
    return st.sampled_from(cases)


def _dimo_test(name: str) -> Callable[..., None]:
    def run(dimo_root: Path, data: st.DataObject) -> None:
        tree = json.loads((dimo_root / "real_jaigo" / "000000" / name).read_text())
        case = data.draw(json_cases(tree, _strict(name), _semantic(name, tree)), label="case")
        with tempfile.TemporaryDirectory() as tmp:
            root = Path(tmp) / "dimo"
            shutil.copytree(dimo_root, root)
            scene_dir = root / "real_jaigo" / "000000"
            models = load_models(root / "models", is_target=lambda i: i < CARRIER_MIN_ID)

            def read() -> object:
                listed = list_dimo_scenes(root / "real_jaigo", "real", DimoSelection.everything())
                return listed, load_dimo_scene(scene_dir, "real", None, models)

            reference = canon(read(), root)
            (scene_dir / name).write_bytes(case.data)
            check(case, read, root, name, reference)

    return given(data=st.data())(run)


test_dimo_scene_camera_json = _dimo_test("scene_camera.json")
test_dimo_scene_gt_json = _dimo_test("scene_gt.json")
test_dimo_scene_gt_world_json = _dimo_test("scene_gt_world.json")
test_dimo_scene_info_json = _dimo_test("scene_info.json")
