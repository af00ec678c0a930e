"""``synth --executor ray`` on a local Ray cluster of two CPUs, started once for the module: the actors send the scene
folders back and this process writes them, so the dataset is byte for byte the one of ``--workers 1`` (every file,
every folder, the done markers and the contact sheets), in each layout; and a resume writes only what is missing."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

ray = pytest.importorskip("ray")

from bop_cender.cli import main  # noqa: E402
from bop_cender.synth.done import marker_path  # noqa: E402
from bop_cender.synth.generate import generate  # noqa: E402
from bop_cender.synth.write_dimo import DimoSpec  # noqa: E402
from bop_cender.synth.write_industrial import IndustrialSynthSpec  # noqa: E402
from bop_cender.synth.write_tless import TlessSpec  # noqa: E402

#: Small sets of each layout (2 or more jobs each, so that both actors write).
SPECS = {
    "dimo": DimoSpec(n_scenes=2, n_viewpoints=2, variants=(0, 17), width=96, height=80, seed=5),
    "tless": TlessSpec(n_scenes=1, n_views=3, pbr_scenes=1, pbr_images=2, width=96, height=72, seed=3),
    "industrial": IndustrialSynthSpec(n_scenes=1, n_images=1, train_scenes=1, parts_per_scene=(10, 10), seed=3),
}


@pytest.fixture(scope="module", autouse=True)
def local_cluster():
    """One Ray instance of 2 CPUs for the module (starting one takes seconds)."""
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


def tree(root: Path) -> dict[str, bytes | None]:
    """Every path under ``root``: a file's bytes, None for a folder."""
    return {p.relative_to(root).as_posix(): p.read_bytes() if p.is_file() else None for p in root.rglob("*")}


@pytest.mark.parametrize("layout", ["dimo", pytest.param("tless", marks=pytest.mark.slow),
                                    pytest.param("industrial", marks=pytest.mark.slow)])  # fmt: skip
def test_ray_writes_the_dataset_of_one_process_byte_for_byte(layout, tmp_path):
    one, cluster = tmp_path / "one", tmp_path / "ray"
    generate(layout, one, SPECS[layout], workers=1, progress=False)
    report = generate(layout, cluster, SPECS[layout], workers=2, progress=False, executor="ray")
    assert report.written > 1 and report.skipped == 0
    mine, theirs = tree(one), tree(cluster)
    assert sorted(theirs) == sorted(mine)
    assert [name for name in mine if mine[name] != theirs[name]] == []
    assert any(name.startswith("contact_sheets/") for name in mine)  # the files outside the folders came back too


@pytest.mark.slow  # 19 s on the shared 2-core machine (a local synth, then a Ray one)
def test_a_ray_resume_writes_only_the_missing_folders_the_same(tmp_path, capsys):
    root = tmp_path / "dimo"
    argv = ["synth", "--layout", "dimo", "--out", str(root), "--scenes", "2", "--views", "2", "--variants", "0,17",
            "--seed", "5", "--no-contact-sheets"]  # fmt: skip
    assert main(argv) == 0
    whole = tree(root)
    gone = root / "sim_jaigo" / "000001_17"
    shutil.rmtree(gone)
    kept = marker_path(root / "real_jaigo" / "000000").stat().st_mtime_ns
    assert main([*argv, "--executor", "ray", "--workers", "2"]) == 0
    assert "resuming: 5 of 6 scene folders done, 1 to go" in capsys.readouterr().err
    assert tree(root) == whole and marker_path(root / "real_jaigo" / "000000").stat().st_mtime_ns == kept
