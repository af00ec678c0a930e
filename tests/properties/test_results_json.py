"""Property tests of the results-side JSON readers: the run sidecar (``read_run_sidecar``) and PVNet's JSON
(``convert_pvnet``, which writes a BOP CSV only when the whole input is good)."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from bop_cender.results.bop_csv import read_bop_results
from bop_cender.results.convert_pvnet import convert_pvnet
from bop_cender.results.files import read_run_sidecar, write_run_sidecar
from tests.properties.mutate import Case, JsonPath, check, dumps, json_cases, replaced

# ---------------------------------------------------------------------------------------------- run sidecar

_TYPED = {"format": "x", "version": 1, "data_root": "/d", "dataset": "tless", "split": "test",
          "selection": {}, "seed": 0, "extra": {}}  # fmt: skip
_WRONG = {str: [5, None, [], True], int: ["1", 1.5, None, True, []], dict: [[], "x", None, 3]}


def _sidecar_seed() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        csv = Path(tmp) / "m_tless-test.csv"
        path = write_run_sidecar(csv, "/data/tless", "tless", "test", {"n_views": 3, "scenes": [1, 2]}, 4, {"a": 1})
        return json.loads(path.read_text())


SIDECAR = _sidecar_seed()


def _sidecar_strict(path: JsonPath, op: str) -> bool:
    return len(path) == 1 and path[0] in _TYPED and op in ("delete", "rename")


def _sidecar_semantic() -> st.SearchStrategy[Case]:
    cases = [Case(dumps(replaced(SIDECAR, (k,), v)), "invalid", f"{k} = {v!r}")
             for k, seed in _TYPED.items() for v in _WRONG[type(seed)]]  # fmt: skip
    cases += [
        Case(dumps(replaced(SIDECAR, ("format",), "bop-cender-runs")), "invalid", "another format"),
        Case(dumps(replaced(SIDECAR, ("version",), 2)), "invalid", "a newer version"),
        Case(b"[]", "invalid", "a list"),
    ]
    return st.sampled_from(cases)


@given(case=json_cases(SIDECAR, _sidecar_strict, _sidecar_semantic()))
def test_run_sidecar(case: Case) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        csv = root / "m_tless-test.csv"
        (root / "m_tless-test.json").write_text(json.dumps(SIDECAR))
        reference = read_run_sidecar(csv)
        (root / "m_tless-test.json").write_bytes(case.data)
        check(case, lambda: read_run_sidecar(csv), root, "m_tless-test.json", reference, lambda d: d)


# ---------------------------------------------------------------------------------------------- PVNet JSON


def _pvnet_seed() -> dict:
    rng = np.random.default_rng(2)

    def pose() -> list:
        R = Rotation.random(random_state=rng).as_matrix()
        t = rng.uniform(-0.1, 0.1, 3) + [0, 0, 0.7]  # metres
        return np.c_[R, t].tolist()

    return {
        "000001/000042": [{"obj_id": 5, "pose": pose(), "score": 0.93, "time": 0.21},
                          {"obj_id": 2, "pose": pose(), "time": 0.21}],
        "test_primesense/000002/rgb/000007.png": [{"obj_id": 5, "pose": pose()}],
    }  # fmt: skip


PVNET = _pvnet_seed()
K1, K2 = list(PVNET)


def _pvnet_strict(path: JsonPath, op: str) -> bool:
    if len(path) == 1:
        return op == "rename"  # an image less is valid; [] is an image without estimates
    if len(path) == 2:
        return op == "bad"  # an estimate less is valid
    if path[2] in ("score", "time"):
        return len(path) > 3 or op == "bad"  # defaults 1.0 and -1
    return path[2] in ("obj_id", "pose")


def _pvnet_semantic() -> st.SearchStrategy[Case]:
    R = np.asarray(PVNET[K1][0]["pose"])[:, :3]
    t = np.asarray(PVNET[K1][0]["pose"])[:, 3]
    mm = {k: [{**e, "pose": (np.asarray(e["pose"]) * [1, 1, 1, 1000]).tolist()} for e in v] for k, v in PVNET.items()}
    cases = [
        Case(dumps(replaced(PVNET, (K1, 0, "pose"), np.c_[R * 1.1, t].tolist())), "invalid", "R scaled"),
        Case(dumps(replaced(PVNET, (K1, 0, "pose"), np.c_[-R, t].tolist())), "invalid", "R a reflection"),
        Case(dumps(replaced(PVNET, (K1, 0, "pose"), np.c_[R, t][:2].tolist())), "invalid", "a 2x4 pose"),
        Case(dumps(replaced(PVNET, (K1, 0, "pose", 0, 0), True)), "invalid", "a bool in the pose"),
        Case(dumps(replaced(PVNET, (K1, 1, "time"), 5.0)), "invalid", "times of one image disagree"),
        Case(dumps(replaced(PVNET, (K1, 0, "obj_id"), -3)), "invalid", "obj_id negative"),
        Case(dumps(replaced(PVNET, (K1, 0, "obj_id"), 1e30)), "invalid", "obj_id 1e30"),
        Case(dumps({"000001/" + "9" * 19: PVNET[K1]}), "invalid", "an image id of 19 digits"),
        Case(dumps(mm), "invalid", "t in millimetres"),
        Case(b"[]", "invalid", "a list"),
    ]
    return st.sampled_from(cases)


@given(case=json_cases(PVNET, _pvnet_strict, _pvnet_semantic()))
def test_pvnet_json(case: Case) -> None:
    """Refused: one error naming the PVNet file and no CSV; accepted: a CSV that the reader reads back as the rows."""
    with tempfile.TemporaryDirectory() as tmp, tempfile.TemporaryDirectory() as out_dir:
        root = Path(tmp)
        source = root / "pvnet.json"
        out = Path(out_dir) / "pvnet_tless-test.csv"
        source.write_text(json.dumps(PVNET))
        reference = _values(convert_pvnet(source, out))
        out.unlink()
        source.write_bytes(case.data)
        rows = check(case, lambda: convert_pvnet(source, out), root, source.name)
        if rows is None:
            assert not out.exists(), f"{case.what}: refused, but the CSV was written"
            return
        written = sorted(rows, key=lambda r: (r.scene_id, r.im_id, -r.score))
        assert _values(read_bop_results(out)) == _values(written), f"{case.what}: the CSV reads back otherwise"
        if case.expect == "same":  # the same rows (in file order, which reordered keys change; the CSV is sorted)
            assert sorted(_values(rows)) == sorted(reference), case.what


def _values(rows: list) -> list[tuple]:
    return [(r.scene_id, r.im_id, r.obj_id, r.score, r.R.tobytes(), r.t.tobytes(), r.time) for r in rows]
