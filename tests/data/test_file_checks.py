"""``bop-cender info`` checks the files run and score read: meshes, colour and depth images; every problem listed."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from bop_cender.cli import main
from bop_cender.data.file_checks import ImageFile, check_image
from bop_cender.data.image_header import read_image_header
from bop_cender.data.tless import open_tless
from bop_cender.errors import DatasetError, DatasetWarning

try:
    from tests.data.bop_builder import BopSpec, build_bop
    from tests.data.dimo_builder import SceneSpec, build_dimo
except ImportError:  # pytest's default import mode puts tests/data itself on sys.path
    from bop_builder import BopSpec, build_bop
    from dimo_builder import SceneSpec, build_dimo

SPEC = BopSpec(n_scenes=2, n_images=3, pbr_scenes=0, target_fraction=1.0, models_dirs=("models_cad", "models_eval"))


@pytest.fixture
def tless(tmp_path: Path) -> Path:
    return build_bop(tmp_path / "tless", SPEC).root


def info(capsys, root: Path, *extra: str, dataset: str = "tless") -> tuple[int, list[str], str]:
    code = main(["info", "--dataset", dataset, "--data-root", str(root), "--no-progress", *extra])
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    return code, out.strip().splitlines(), err


def problems(lines: list[str]) -> list[str]:
    return [line.removeprefix("problem   ") for line in lines if line.startswith("problem   ")]


def a_view(root: Path, scene: int = 1, view: int = 1):
    """A view the split uses (T-LESS test: only target images), of the second scene by default."""
    ds = open_tless(root, "test", n_views=5)
    return ds.scene(ds.scene_keys[scene]).views[view]


def test_a_clean_dataset_is_described_and_checked(tless: Path, capsys) -> None:
    code, lines, _ = info(capsys, tless)
    assert code == 0 and lines[0] == "dataset   tless, split test" and not problems(lines)
    assert lines[-1] == "checked 6 meshes, 12 images (headers): no problem found"  # 3 models x 2 folders; rgb + depth
    code, lines, _ = info(capsys, tless, "--deep")
    assert code == 0 and lines[-1] == "checked 6 meshes, 12 images (decoded): no problem found"


def _nan_vertex(text: str) -> str:
    lines = text.splitlines()
    first = lines.index("end_header") + 1
    lines[first] = " ".join(["nan", *lines[first].split()[1:]])
    return "\n".join(lines) + "\n"


def _face_out_of_range(text: str) -> str:
    lines = text.splitlines()
    face = next(i for i, line in enumerate(lines) if line.startswith("3 ") and i > lines.index("end_header"))
    lines[face] = "3 0 1 99999"
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    ("corrupt", "message"),
    [
        (_nan_vertex, "vertex: 1 vertex coordinate(s) NaN or infinite (first: vertex 0)"),
        (_face_out_of_range, "face: 1 face(s) index vertices outside 0.."),
        (lambda text: text[: len(text) // 2], "truncated: the file ends before"),
    ],
    ids=["nan-vertex", "face-index", "truncated"],
)
def test_a_corrupted_mesh_is_one_line_naming_the_file(tless: Path, capsys, corrupt, message: str) -> None:
    ply = tless / "models_eval" / "obj_000002.ply"  # what score reads (run reads models_cad/)
    ply.write_text(corrupt(ply.read_text()))
    code, lines, _ = info(capsys, tless)
    assert code == 2
    [problem] = problems(lines)
    assert problem.startswith(f"{ply}: ") and message in problem
    assert lines[-1] == "checked 6 meshes, 12 images (headers): 1 problem"


def test_a_truncated_png_is_caught_by_deep_not_by_the_header_check(tless: Path, capsys) -> None:
    rgb = a_view(tless).rgb_path
    data = rgb.read_bytes()
    rgb.write_bytes(data[: len(data) - 20])  # the header intact, the end of the pixel data and IEND gone
    code, lines, _ = info(capsys, tless)
    assert code == 0 and lines[-1].endswith("(headers): no problem found")
    code, lines, err = info(capsys, tless, "--deep")
    assert code == 2 and problems(lines) == [f"{rgb}: cannot decode image"]
    assert "libpng" not in err  # the decoder's own message is silenced: ours names the file


def test_a_wrong_size_image_and_an_8_bit_depth_image_are_each_listed(tless: Path, capsys) -> None:
    view = a_view(tless)
    cv2.imwrite(str(view.rgb_path), np.zeros((30, 40, 3), np.uint8))
    cv2.imwrite(str(view.depth_path), np.full((24, 32), 7, np.uint8))
    for deep in ((), ("--deep",)):
        code, lines, _ = info(capsys, tless, *deep)
        assert code == 2 and lines[-1].endswith(": 2 problems")
        found = problems(lines)
        assert f"{view.rgb_path}: size: image is 40x30, expected 32x24 (the split's image size)" in found
        [depth] = [p for p in found if p.startswith(str(view.depth_path))]
        assert "expected a 16-bit depth image, got 8-bit" in depth


def test_every_problem_is_listed_a_broken_scene_included(tless: Path, capsys) -> None:
    ply = tless / "models_cad" / "obj_000001.ply"
    ply.write_text(_nan_vertex(ply.read_text()))
    gt = tless / "test_primesense" / "000002" / "scene_gt.json"  # read when the scene loads, not when the split opens
    gt.write_text("{")
    code, lines, _ = info(capsys, tless)
    found = problems(lines)
    assert code == 2 and len(found) == 2 and lines[-1] == "checked 6 meshes, 6 images (headers): 2 problems"
    assert found[0].startswith(f"{gt}: malformed JSON") and found[1].startswith(f"{ply}: vertex:")
    assert "scenes    1" in lines  # the scene that loads is described and checked


def test_a_wrong_sized_first_image_is_the_one_reported(tless: Path, capsys) -> None:
    """The split's size is voted by a few images and the camera file, not read from the first image: a
    wrong-sized first image used to become the reference, and every other image was blamed instead."""
    first = sorted((tless / "test_primesense" / "000001" / "rgb").iterdir())[0]
    cv2.imwrite(str(first), np.zeros((12, 16, 3), np.uint8))
    code, lines, _ = info(capsys, tless)
    assert code == 2 and problems(lines) == [f"{first}: size: image is 16x12, expected 32x24 (the split's image size)"]
    assert "  - image size 32x24 (camera_primesense.json, checked on 7 of 8 sampled images)" in lines


def test_a_camera_file_that_no_image_agrees_with_still_yields_to_the_images(tless: Path) -> None:
    for path in (tless / "test_primesense").rglob("*.png"):
        if path.parent.name in ("rgb", "depth"):
            image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            cv2.imwrite(str(path), cv2.resize(image, (16, 12), interpolation=cv2.INTER_NEAREST))
    with pytest.warns(DatasetWarning, match=r"says 32x24 but .* is 16x12 \(as 8 of 8 sampled images are\)"):
        ds = open_tless(tless, "test", n_views=5)
    assert ds.image_size == (16, 12)


def test_dimo_a_wrong_sized_first_image_is_the_one_reported(tmp_path: Path, capsys) -> None:
    root = tmp_path / "dimo"
    build_dimo(root, [SceneSpec(folder="000000"), SceneSpec(folder="000001")])
    rgb = root / "real_jaigo" / "000000" / "rgb" / "000000.png"
    cv2.imwrite(str(rgb), np.zeros((12, 20, 3), np.uint8))
    code, lines, _ = info(capsys, root, dataset="dimo")
    assert code == 2 and problems(lines) == [f"{rgb}: size: image is 20x12, expected 16x12 (the split's image size)"]


def test_dimo_images_are_checked_against_the_split_size(tmp_path: Path, capsys) -> None:
    root = tmp_path / "dimo"
    build_dimo(root, [SceneSpec(folder="000000"), SceneSpec(folder="000001")])
    code, lines, _ = info(capsys, root, dataset="dimo")
    assert code == 0 and lines[-1] == "checked 3 meshes, 4 images (headers): no problem found"  # viewpoints 0, 2
    rgb = root / "real_jaigo" / "000001" / "rgb" / "000002.png"
    cv2.imwrite(str(rgb), np.zeros((12, 20, 3), np.uint8))
    code, lines, _ = info(capsys, root, dataset="dimo")
    assert code == 2 and problems(lines) == [f"{rgb}: size: image is 20x12, expected 16x12 (the split's image size)"]


def test_a_jpeg_cut_short_decodes_but_deep_catches_it(tmp_path: Path) -> None:
    path = tmp_path / "000000.jpg"
    cv2.imwrite(str(path), np.random.default_rng(0).integers(0, 255, (24, 32, 3), dtype=np.uint8))
    image = ImageFile(path, (32, 24))
    assert check_image(image, deep=True) is None
    path.write_bytes(path.read_bytes()[:-200])
    assert check_image(image, deep=False) is None  # the header is intact
    assert (
        check_image(image, deep=True)
        == f"{path}: JPEG cut short (no end-of-image marker): the decoder fills the rest grey"
    )


def test_headers_are_read_without_decoding(tmp_path: Path) -> None:
    cv2.imwrite(str(tmp_path / "d.png"), np.zeros((5, 7), np.uint16))
    cv2.imwrite(str(tmp_path / "c.jpg"), np.zeros((5, 7, 3), np.uint8))
    header = read_image_header(tmp_path / "d.png")
    assert (header.format, header.width, header.height, header.bit_depth, header.channels) == ("png", 7, 5, 16, 1)
    header = read_image_header(tmp_path / "c.jpg")  # after its JFIF segment and tables
    assert (header.format, header.width, header.height, header.bit_depth, header.channels) == ("jpeg", 7, 5, 8, 3)
    (tmp_path / "x.txt").write_text("not an image")
    assert read_image_header(tmp_path / "x.txt") is None
    (tmp_path / "cut.png").write_bytes((tmp_path / "d.png").read_bytes()[:20])
    with pytest.raises(DatasetError, match="PNG header cut or malformed"):
        read_image_header(tmp_path / "cut.png")


def test_targets_asking_for_more_instances_than_the_ground_truth_are_each_listed(tless: Path, capsys) -> None:
    """info applies score's inst_count check (score refuses the first such target; info lists them all)."""
    path = tless / "test_targets_bop19.json"
    targets = json.loads(path.read_text())
    targets[0]["inst_count"] = 9
    targets[-1]["inst_count"] = 7
    path.write_text(json.dumps(targets))
    code, lines, _ = info(capsys, tless)
    found = problems(lines)
    assert code == 2 and len(found) == 2 and lines[-1].endswith(": 2 problems")
    first = targets[0]
    assert found[0].startswith(f"{path}: inst_count: the target of scene {first['scene_id']}, image {first['im_id']},")
    assert "has inst_count 9, but the image's ground truth has " in found[0]
    assert "has inst_count 7" in found[1]
    path.write_text("{")  # T-LESS selects its images by the targets: the split does not open
    code, _, err = info(capsys, tless)
    assert code == 2 and f"{path}: malformed JSON" in err


def test_a_mesh_without_a_models_info_entry_is_a_note(tless: Path, capsys) -> None:
    stray = tless / "models_cad" / "obj_000042.ply"
    stray.write_bytes((tless / "models_cad" / "obj_000001.ply").read_bytes())
    code, lines, _ = info(capsys, tless)
    assert (
        code == 0
        and f"note      {stray}: no entry 42 in models_info.json: not loaded (neither scored nor an occluder)" in lines
    )


def test_a_broken_file_of_several_view_groups_is_one_problem() -> None:
    """A scene of 8 images in groups of 5 is two scene keys over one scene_gt.json: one problem, not two."""
    from types import SimpleNamespace

    from bop_cender.data.describe import summarise

    def scene(key: str):
        if key.startswith("000001"):
            raise DatasetError("malformed JSON", file="test/000001/scene_gt.json")
        raise DatasetError("another", file=f"test/{key}/scene_camera.json")

    keys = ["000001/g00", "000001/g01", "000002/g00"]
    summary = summarise(SimpleNamespace(scene_keys=keys, scene=scene, models={}), progress=False, keep_going=True)
    assert summary.problems == [
        "test/000001/scene_gt.json: malformed JSON (scenes 000001/g00, 000001/g01: the same error)",
        "test/000002/g00/scene_camera.json: another",
    ]
    assert summary.scenes == 0 and summary.loaded == []
    many = [f"000001/g{k:02d}" for k in range(8)]
    summary = summarise(SimpleNamespace(scene_keys=many, scene=scene, models={}), progress=False, keep_going=True)
    assert summary.problems == [
        "test/000001/scene_gt.json: malformed JSON (scenes 000001/g00, 000001/g01, 000001/g02, 000001/g03, 000001/g04"
        " and 3 more: the same error)"
    ]


def test_a_scene_without_colour_images_is_a_problem(tless: Path, capsys) -> None:
    """With its rgb/ folder gone, info checked the depth images alone and found no problem; run then failed."""
    import shutil

    folder = tless / "test_primesense" / "000001"
    shutil.rmtree(folder / "rgb")
    code, lines, _ = info(capsys, tless)
    found = problems(lines)
    assert code == 2 and len(found) == 1, lines
    assert found[0].startswith(f"{folder}: scene 000001") and "no colour image of 3 view(s)" in found[0]
