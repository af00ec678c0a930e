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
        Case(dumps(replaced(SIDECAR, ("version",), 0)), "invalid", "version 0"),
        Case(dumps(replaced(SIDECAR, ("seed",), -3)), "invalid", "a negative seed"),
        Case(dumps(replaced(SIDECAR, ("data_root",), "")), "invalid", "an empty data root"),
        Case(dumps(replaced(SIDECAR, ("dataset",), "")), "invalid", "an empty dataset"),
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


# ------------------------------------------------------------------------------ PVNet folder of .npy poses


def _npy_pose(seed: int) -> np.ndarray:
    pose = np.zeros((3, 4))
    pose[:, :3] = Rotation.from_euler("xyz", [seed, 2 * seed, 0.5], degrees=False).as_matrix()
    pose[:, 3] = [0.01 * seed, -0.02, 0.6]  # metres, as PVNet writes
    return pose


NPY_FILES = {"000001_000003_000002.npy": _npy_pose(1), "000001_000004_000005.npy": _npy_pose(2)}


@st.composite
def npy_cases(draw: st.DrawFn) -> tuple[dict[str, bytes], str, str]:
    """The folder's files (name -> bytes), what is expected and what changed."""
    import io

    def save(array: np.ndarray) -> bytes:
        buffer = io.BytesIO()
        np.save(buffer, array, allow_pickle=False)
        return buffer.getvalue()

    files = {name: save(a) for name, a in NPY_FILES.items()}
    name = draw(st.sampled_from(sorted(files)))
    kind = draw(st.sampled_from(["same", "stack", "nan", "shape", "rotation", "name", "truncated", "bytes", "units"]))
    pose = NPY_FILES[name].copy()
    if kind == "same":
        return files, "same", "unchanged"
    if kind == "stack":  # several poses of one object in one file: valid
        files[name] = save(np.stack([pose, pose]))
        return files, "either", "two poses in one file"
    if kind == "nan":
        pose[draw(st.integers(0, 2)), draw(st.integers(0, 3))] = draw(st.sampled_from([np.nan, np.inf]))
        files[name] = save(pose)
    elif kind == "shape":
        files[name] = save(draw(st.sampled_from([pose[:, :3], pose.reshape(-1), np.zeros((4, 4)), np.zeros(0)])))
    elif kind == "rotation":
        pose[:, :3] *= draw(st.sampled_from([2.0, 0.5, -1.0]))  # scaled or reflected: not a rotation
        files[name] = save(pose)
    elif kind == "name":
        files[draw(st.sampled_from(["pose.npy", "000001_x_2.npy", "1_2.npy"]))] = files.pop(name)
    elif kind == "truncated":
        files[name] = files[name][: draw(st.integers(0, len(files[name]) - 1))]
    elif kind == "bytes":
        files[name] = b"not an npy file"
    else:  # millimetres where metres are documented
        pose[:, 3] *= 1000.0
        files[name] = save(pose)
        return files, "either", "translation in mm (refused with a dataset, undecided without)"
    return files, "invalid", kind


@given(case=npy_cases())
def test_pvnet_npy_folder(case: tuple[dict[str, bytes], str, str]) -> None:
    """Refused: one error naming a file of the folder, no CSV; accepted: a CSV the reader reads back as the rows."""
    files, expect, what = case
    with tempfile.TemporaryDirectory() as tmp, tempfile.TemporaryDirectory() as out_dir:
        root = Path(tmp)
        for name, data in files.items():
            (root / name).write_bytes(data)
        out = Path(out_dir) / "pvnet_tless-test.csv"
        names = tuple(files) + (root.name,)
        rows = check(Case(b"", expect, what), lambda: convert_pvnet(root, out), root, names)  # type: ignore[arg-type]
        if rows is None:
            assert not out.exists(), f"{what}: refused, but the CSV was written"
            return
        written = sorted(rows, key=lambda r: (r.scene_id, r.im_id, -r.score))
        assert _values(read_bop_results(out)) == _values(written), f"{what}: the CSV reads back otherwise"
