"""PVNet-style 3x4 poses (t in metres) -> BOP results CSV (t in mm)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bop_cender.cli import main
from bop_cender.errors import ResultsError, ResultsWarning
from bop_cender.results.bop_csv import read_bop_results
from bop_cender.results.convert_pvnet import convert_pvnet, read_pvnet_folder, read_pvnet_json

R = Rotation.from_euler("xyz", [10, 20, 30], degrees=True).as_matrix()


def pose(t_m: list[float]) -> np.ndarray:
    return np.concatenate([R, np.asarray(t_m, float)[:, None]], axis=1)  # (3, 4), t in metres


def test_npy_folder_flat_and_per_scene_metres_to_mm(tmp_path: Path) -> None:
    src = tmp_path / "pvnet"
    src.mkdir()
    np.save(src / "000001_000042_000005.npy", pose([0.1, -0.05, 0.7]))
    (src / "000002").mkdir()
    np.save(src / "000002" / "7_3.npy", np.stack([pose([0.0, 0.0, 0.8]), pose([0.01, 0.02, 0.9])]))  # two instances
    rows = read_pvnet_folder(src)
    assert [(r.scene_id, r.im_id, r.obj_id) for r in rows] == [(1, 42, 5), (2, 7, 3), (2, 7, 3)]
    np.testing.assert_allclose(rows[0].t, [100.0, -50.0, 700.0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(rows[2].t, [10.0, 20.0, 900.0], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(rows[0].R, R)
    assert all(r.score == 1.0 and r.time == -1.0 for r in rows)

    out = tmp_path / "pvnet_tless-test.csv"
    convert_pvnet(src, out)
    back = read_bop_results(out)
    assert sorted(tuple(r.t) for r in back) == sorted(tuple(r.t) for r in rows)


def test_json_with_image_paths_scores_and_times(tmp_path: Path) -> None:
    src = tmp_path / "pvnet.json"
    src.write_text(json.dumps({
        "test_primesense/000001/rgb/000042.png": [{"obj_id": 5, "pose": pose([0.1, 0.0, 0.7]).tolist(), "score": 0.8,
                                                    "time": 0.25}],
        "000123_17/3": [{"obj_id": 2, "pose": pose([0.0, 0.0, 0.5]).tolist()}],
    }))  # fmt: skip
    rows = read_pvnet_json(src)
    assert [(r.scene_id, r.im_id, r.obj_id, r.score, r.time) for r in rows] == [
        (1, 42, 5, 0.8, 0.25),
        (12317, 3, 2, 1.0, -1.0),  # DIMO folder 000123_17 -> 12317, default score and unknown time
    ]
    assert rows[1].t[2] == pytest.approx(500.0)


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("000001_42.npy", pose([0, 0, 1]), "expected {scene}_{im_id}_{obj_id}.npy"),
        ("000001_000042_000005.npy", np.zeros((3, 3)), "expected a 3x4 pose"),
        ("000001_000042_000005.npy", np.concatenate([2 * R, np.zeros((3, 1))], 1), "not a rotation"),
        ("000001_000042_000005.npy", pose([0, 0, 1]) + 1e-3j, "expected real numbers .* got complex ones"),
    ],
)
def test_bad_inputs_name_the_file(tmp_path: Path, name: str, content: np.ndarray, message: str) -> None:
    src = tmp_path / "in"
    src.mkdir()
    np.save(src / name, content)
    with pytest.raises(ResultsError, match=message) as info:
        read_pvnet_folder(src)
    assert name in info.value.format()


def test_unknown_objects_and_the_cli(tmp_path: Path, capsys) -> None:
    src = tmp_path / "in"
    src.mkdir()
    np.save(src / "000001_000000_000009.npy", pose([0, 0, 1]))
    with pytest.raises(ResultsError, match=r"unknown object id\(s\) \[9\]"):
        convert_pvnet(src, tmp_path / "pvnet_tless-test.csv", known_obj_ids=[1, 2])
    root = tmp_path / "ds" / "models_eval"
    root.mkdir(parents=True)
    (root / "models_info.json").write_text(json.dumps({"9": {}}))
    out = tmp_path / "pvnet_tless-test.csv"
    assert main(["convert-pvnet", str(src), "--out", str(out), "--data-root", str(tmp_path / "ds")]) == 0
    assert "wrote 1 estimates" in capsys.readouterr().out
    assert read_bop_results(out)[0].t[2] == pytest.approx(1000.0)
    out.unlink()
    assert main(["convert-pvnet", str(src), "--out", str(out), "--dataset-root", str(tmp_path / "ds")]) == 0
    assert "warning: --dataset-root is deprecated: use --data-root" in capsys.readouterr().err and out.is_file()
    both = ["--data-root", str(tmp_path / "ds"), "--dataset-root", str(tmp_path / "ds")]
    assert main(["convert-pvnet", str(src), "--out", str(out), *both]) == 2
    assert "--dataset-root: give --data-root alone" in capsys.readouterr().err
    assert main(["convert-pvnet", str(src), "--out", str(out), "--data-root", str(out)]) == 2
    assert capsys.readouterr().err == f"error: {out}: --data-root: is a file, expected a dataset root folder\n"


def test_translations_in_millimetres_are_refused(tmp_path: Path, capsys) -> None:
    """821 m parts: t written in mm where metres are documented. Refused, with the models' diameters where
    known (a 20 mm part 15 m away is 750 diameters: implausible, though 15 m alone is not)."""
    src = tmp_path / "in"
    src.mkdir()
    mm = [pose([120.0, -40.0, 812.0]), pose([110.0, -30.0, 815.0]), pose([0.1, 0.0, 0.8])]  # one plausible
    np.save(src / "000001_000000_000001.npy", np.stack(mm))
    out = tmp_path / "pvnet_tless-test.csv"
    with pytest.raises(ResultsError, match=r"t: implausible translations: .* a median 822 m from the camera; .*metres"):
        convert_pvnet(src, out)
    np.save(src / "000001_000000_000001.npy", pose([0.0, 0.0, 15.0]))
    convert_pvnet(src, out)  # 15 m: plausible for some camera, without the models
    with pytest.raises(ResultsError, match=r"a median 750 model diameters \(15 m\)"):
        convert_pvnet(src, out, diameters={1: 20.0})
    np.save(src / "000001_000000_000001.npy", pose([0.0, 0.0, 0.8]))
    assert len(convert_pvnet(src, out, diameters={1: 20.0})) == 1  # 40 diameters
    models = tmp_path / "ds" / "models_eval"
    models.mkdir(parents=True)
    (models / "models_info.json").write_text(json.dumps({"1": {"diameter": 0.02}}))  # a diameter in metres
    assert main(["convert-pvnet", str(src), "--out", str(out), "--data-root", str(tmp_path / "ds")]) == 2
    assert (
        "t: implausible translations: the objects would lie a median 40,000 model diameters" in capsys.readouterr().err
    )


def test_a_non_finite_object_id_is_one_error(tmp_path: Path) -> None:
    src = tmp_path / "pvnet.json"
    entry = json.dumps({"obj_id": float("inf"), "pose": pose([0, 0, 0.5]).tolist()})  # json writes Infinity
    src.write_text(f'{{"000001/3": [{entry}]}}')
    with pytest.raises(ResultsError, match=r"obj_id: expected a non-negative integer, got inf"):
        read_pvnet_json(src)


@pytest.mark.parametrize(
    ("content", "message"), [("{}", "no estimates in it"), ("[]", "expected an object mapping image keys")]
)
def test_an_input_without_estimates_writes_nothing(tmp_path: Path, capsys, content: str, message: str) -> None:
    """A header-only CSV would be refused by `score` later: the conversion refuses it now, naming the input."""
    source = tmp_path / "empty.json"
    source.write_text(content)
    out = tmp_path / "pvnet_tless-test.csv"
    assert main(["convert-pvnet", str(source), "--out", str(out)]) == 2
    assert f"empty.json: {message}" in capsys.readouterr().err and not out.exists()


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('{{"000001/3": [{e}], "000001/3": [{e}]}}', "repeats the key '000001/3'"),
        ('{{"000001/3": [{{"obj_id": 5, "obj_id": 6, "pose": {p}}}]}}', "repeats the key 'obj_id'"),
        ('{{"000001/3": [{{"obj_id": 5, "pose": {p}, "Score": 0.2}}]}}', r"000001/3\[0\]: unknown field\(s\) 'Score'"),
    ],
)
def test_json_input_that_would_lose_a_value_is_refused(tmp_path: Path, text: str, message: str) -> None:
    """A repeated key (json keeps the last value) or a misspelled field (score 1.0 in its place) is one error."""
    p = json.dumps(pose([0, 0, 0.5]).tolist())
    src = tmp_path / "pvnet.json"
    src.write_text(text.format(e=json.dumps({"obj_id": 5, "pose": pose([0, 0, 0.5]).tolist()}), p=p))
    with pytest.raises(ResultsError, match=message) as info:
        read_pvnet_json(src)
    assert "pvnet.json" in info.value.format()


def test_one_image_or_object_given_twice_is_refused(tmp_path: Path) -> None:
    """Two names of one file (a fuzz: 000001_000000_000010.npy beside 1_0_10.npy, a flat file beside a scene
    folder's) or two keys of one image in JSON counted its poses twice, without a word."""
    src = tmp_path / "in"
    src.mkdir()
    np.save(src / "000001_000000_000010.npy", pose([0.0, 0.0, 0.7]))
    np.save(src / "1_0_10.npy", pose([0.0, 0.0, 0.7]))
    with pytest.raises(ResultsError, match=r"scene 1, image 0, object 10 again \(first in .*000001_000000_000010.npy"):
        read_pvnet_folder(src)
    (src / "1_0_10.npy").unlink()
    (src / "poses.npz").write_bytes(b"")
    with pytest.warns(ResultsWarning, match=r"1 file\(s\) other than .npy not read \(first: poses.npz\)"):
        assert len(read_pvnet_folder(src)) == 1
    (src / "000001").mkdir()
    np.save(src / "000001" / "000000_000010.npy", pose([0.0, 0.0, 0.7]))
    with pytest.raises(ResultsError, match="object 10 again"):
        read_pvnet_folder(src)
    doc = tmp_path / "pvnet.json"
    entry = [{"obj_id": 5, "pose": pose([0.0, 0.0, 0.7]).tolist()}]
    doc.write_text(json.dumps({"000001/000000": entry, "test_primesense/000001/rgb/000000.png": entry}))
    with pytest.raises(ResultsError, match=r"scene 1, image 0 again \(first as '000001/000000'\)"):
        read_pvnet_json(doc)


def test_an_unknown_time_beside_a_known_one_in_an_image_is_refused(tmp_path: Path) -> None:
    """The toolkit compares every time of an image, -1 included: a converted file would fail it."""
    doc = tmp_path / "pvnet.json"
    doc.write_text(json.dumps({"000001/000000": [{"obj_id": 5, "pose": pose([0.0, 0.0, 0.7]).tolist(), "time": 0.5},
                                                 {"obj_id": 6, "pose": pose([0.0, 0.1, 0.7]).tolist()}]}))  # fmt: skip
    with pytest.raises(ResultsError, match=r"time -1.0 \(unknown: no time, or a negative one\) differs from 0.5 s"):
        read_pvnet_json(doc)


def test_with_a_data_root_scenes_and_images_are_checked_against_the_named_split(tmp_path: Path, capsys) -> None:
    """An unknown scene or image converted with exit 0 (score refused it later); now the split the output's name says
    is opened and every row checked, as score checks them. A split that does not open there is said."""
    from tests.data.bop_builder import BopSpec, build_bop

    spec = BopSpec(n_scenes=1, n_images=3, pbr_scenes=0, target_fraction=1.0, models_dirs=("models_cad", "models_eval"))
    root = build_bop(tmp_path / "tless", spec).root
    gt = json.loads((root / "test_primesense" / "000001" / "scene_gt.json").read_text())
    first = gt["0"][0]
    t_m = (np.asarray(first["cam_t_m2c"]) / 1000.0).tolist()
    R_gt = np.asarray(first["cam_R_m2c"]).reshape(3, 3)
    entry = [{"obj_id": first["obj_id"], "pose": np.concatenate([R_gt, np.asarray(t_m)[:, None]], 1).tolist()}]
    out = tmp_path / "pvnet_tless-test.csv"
    for key, message in (("000009/000000", "scene_id: no scene 9 in tless test"),
                         ("000001/000999", "im_id: scene 1 has no image 999")):  # fmt: skip
        doc = tmp_path / "pvnet.json"
        doc.write_text(json.dumps({key: entry}))
        assert main(["convert-pvnet", str(doc), "--out", str(out), "--data-root", str(root)]) == 2
        assert message in capsys.readouterr().err and not out.exists()
    doc.write_text(json.dumps({"000001/000000": entry}))
    assert main(["convert-pvnet", str(doc), "--out", str(out), "--data-root", str(root)]) == 0
    assert len(read_bop_results(out)) == 1
    other = ["convert-pvnet", str(doc), "--out", str(tmp_path / "pvnet_dimo-sim.csv"), "--data-root", str(root)]
    assert main(other) == 0  # not DIMO's layout at that root: said, and the ids left to score
    assert "warning: scenes and images not checked: " in capsys.readouterr().err
    import shutil  # a BOP dataset of several models folders: its split opens with the one --model-type names

    lmo = shutil.copytree(root, tmp_path / "lmo")
    doc.write_text(json.dumps({"000001/000999": entry}))
    named = ["convert-pvnet", str(doc), "--out", str(tmp_path / "pvnet_lmo-test.csv"), "--data-root", str(lmo)]
    assert main(named) == 0 and "choose one with --model-type" in capsys.readouterr().err
    assert main([*named, "--model-type", "cad"]) == 2
    assert "im_id: scene 1 has no image 999" in capsys.readouterr().err
    assert main(["convert-pvnet", str(doc), "--out", str(out), "--model-type", "cad"]) == 2
    assert "--model-type: chooses the models folder of --data-root" in capsys.readouterr().err


def test_a_split_whose_ground_truth_is_withheld_converts_with_a_warning(tmp_path: Path, capsys) -> None:
    """A BOP test split without scene_gt.json (ITODD, HB: GT withheld): its ids cannot be checked, which is said;
    the conversion is not refused (it was, for a moment, by the id check)."""
    from tests.data.bop_builder import BopSpec, build_bop

    spec = BopSpec(n_scenes=1, n_images=3, pbr_scenes=0, target_fraction=1.0, models_dirs=("models_cad", "models_eval"))
    root = build_bop(tmp_path / "tless", spec).root
    (root / "test_primesense" / "000001" / "scene_gt.json").unlink()
    doc = tmp_path / "pvnet.json"
    doc.write_text(json.dumps({"000001/000000": [{"obj_id": 1, "pose": pose([0.0, 0.0, 0.7]).tolist()}]}))
    out = tmp_path / "pvnet_tless-test.csv"
    assert main(["convert-pvnet", str(doc), "--out", str(out), "--data-root", str(root)]) == 0
    assert "warning: scenes and images not checked: " in capsys.readouterr().err and out.is_file()
