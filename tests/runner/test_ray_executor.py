"""``run --executor ray`` on a local Ray cluster of two CPUs, started once for the module: the rows of ``--workers 1``,
a failing scene and a killed worker reported as failed scenes (never a failed run), resume across executors, the
figures sent back, and the errors of a node without the data, of Ray missing and of an address that does not answer.

The actors' hooks (a method that fails on a scene, a process that exits on a scene) are subclasses of
:class:`~bop_cender.runner.ray_executor.SceneWorker` defined here and sent to the actors by value.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
from dataclasses import replace
from pathlib import Path

import pytest

ray = pytest.importorskip("ray")

sys.path.insert(0, str(Path(__file__).parents[1]))
import method_data  # noqa: E402

import bop_cender.runner.ray_executor as ray_executor  # noqa: E402
from bop_cender import cluster  # noqa: E402
from bop_cender.cli import main  # noqa: E402
from bop_cender.data.dimo import open_dimo  # noqa: E402
from bop_cender.errors import ConfigError, DatasetError  # noqa: E402
from bop_cender.runner import run, work_dir  # noqa: E402
from bop_cender.runner.ray_executor import SceneWorker, ray_scenes  # noqa: E402

CHEAP = method_data.CHEAP
CLI_CHEAP = ["--candidates", "48", "--top-k", "2", "--set", "poses.refine.nelder_mead.maxfev=40"]
OUT = "cendernet-oracle_dimo-real.csv"


@pytest.fixture(scope="module", autouse=True)
def local_cluster():
    """One Ray instance of 2 CPUs for the module (starting one takes seconds); the actors' hook classes of this
    module travel by value (a test module is not importable on the workers)."""
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    yield
    ray.cloudpickle.unregister_pickle_by_value(sys.modules[__name__])
    ray.shutdown()


@pytest.fixture(scope="module")
def mini_root(tmp_path_factory) -> Path:
    return method_data.build(tmp_path_factory.mktemp("ray") / "dimo", n_scenes=2)


request = method_data.cheap_request


@pytest.fixture(scope="module")
def reference_csv(mini_root, tmp_path_factory) -> Path:
    """The rows of one process (``--workers 1``), made by the command line as the Ray run below is."""
    out = tmp_path_factory.mktemp("ref") / OUT
    argv = ["run", "--heatmaps", "oracle", "--dataset", "dimo", "--data-root", str(mini_root), "--out", str(out),
            "--no-progress", "--deterministic-time", "--workers", "1", *CLI_CHEAP]  # fmt: skip
    assert main(argv) == 0
    return out


def test_ray_gives_the_rows_of_one_process_and_sends_the_figures_back(mini_root, reference_csv, tmp_path, capsys):
    out, vis = tmp_path / OUT, tmp_path / "vis"
    argv = ["run", "--heatmaps", "oracle", "--dataset", "dimo", "--data-root", str(mini_root), "--out", str(out),
            "--no-progress", "--deterministic-time", "--executor", "ray", "--workers", "2", "--vis", str(vis),
            *CLI_CHEAP]  # fmt: skip
    assert main(argv) == 0, capsys.readouterr().err
    assert out.read_bytes() == reference_csv.read_bytes()
    assert json.loads(out.with_suffix(".json").read_text())["extra"]["executor"] == "ray"
    figures = sorted(vis.iterdir())
    assert [p.name for p in figures] == ["000000.png", "000001.png"]
    assert all(p.read_bytes().startswith(b"\x89PNG") for p in figures)


class FailsOnScene(SceneWorker):
    """An actor whose method raises on scene :attr:`key` (an unreadable input, say)."""

    key = "000001"

    def estimate(self, key):
        if key != self.key:
            return super().estimate(key)

        def broken(scene):
            raise RuntimeError("rgb/000000.png: truncated image")

        self.state.method.run_scene = broken  # this scene only: the actor's next scene runs the method
        try:
            return super().estimate(key)
        finally:
            del self.state.method.run_scene


def test_a_failing_scene_is_a_failed_scene_and_resume_on_another_executor_redoes_only_it(
    mini_root, reference_csv, tmp_path, monkeypatch
):
    monkeypatch.setattr(ray_executor, "SceneWorker", FailsOnScene)
    out = tmp_path / OUT
    summary = run(request(mini_root, out, executor="ray", workers=2))
    assert summary.failed == {"000001": "RuntimeError: rgb/000000.png: truncated image"}
    assert json.loads(out.with_suffix(".json").read_text())["extra"]["failed_scenes"] == summary.failed
    monkeypatch.undo()
    again = run(request(mini_root, out, resume=True))  # the local executor keeps the Ray run's shards
    assert (again.resumed, again.failed) == (1, {}) and not work_dir(out).exists()
    assert out.read_bytes() == reference_csv.read_bytes()


class DiesOnScene(SceneWorker):
    """An actor whose process exits on scene :attr:`key`: the first :attr:`deaths` times it is given (counted in
    files under :attr:`flags`, which outlive the process), every time when :attr:`deaths` is None."""

    key = "000001"
    flags = ""
    deaths: int | None = 1

    def estimate(self, key):
        if key == self.key:
            died = len(list(Path(self.flags).iterdir()))
            if self.deaths is None or died < self.deaths:
                (Path(self.flags) / str(died)).touch()
                os._exit(1)
        return super().estimate(key)


def test_a_killed_worker_is_restarted_and_its_scene_run_again(mini_root, reference_csv, tmp_path, monkeypatch):
    flags = tmp_path / "deaths"
    flags.mkdir()
    monkeypatch.setattr(DiesOnScene, "flags", str(flags))
    monkeypatch.setattr(ray_executor, "SceneWorker", DiesOnScene)
    out = tmp_path / OUT
    summary = run(request(mini_root, out, executor="ray", workers=2))
    assert len(list(flags.iterdir())) == 1 and not summary.failed
    assert out.read_bytes() == reference_csv.read_bytes()


@pytest.mark.slow  # 16 s on the shared 2-core machine: three actor restarts
def test_a_scene_that_kills_every_try_is_a_failed_scene_not_a_failed_run(mini_root, tmp_path, monkeypatch):
    flags = tmp_path / "deaths"
    flags.mkdir()
    monkeypatch.setattr(DiesOnScene, "flags", str(flags))
    monkeypatch.setattr(DiesOnScene, "deaths", None)
    monkeypatch.setattr(ray_executor, "SceneWorker", DiesOnScene)
    out = tmp_path / OUT
    summary = run(request(mini_root, out, executor="ray", workers=2))
    # Ray's tries (it may count a try that found the actor restarting), then the scene's failure
    assert 2 <= len(list(flags.iterdir())) <= 1 + cluster.TASK_RETRIES
    assert list(summary.failed) == ["000001"] and "the Ray worker running it failed" in summary.failed["000001"]
    assert summary.scenes == 2 and summary.estimates > 0 and work_dir(out).is_dir()


def test_the_executor_is_not_in_the_fingerprint(mini_root, tmp_path):
    local = request(mini_root, tmp_path / OUT)
    assert local.fingerprint() == replace(local, executor="ray", workers=None, address="auto").fingerprint()


def test_a_node_without_the_data_is_one_error_naming_it_and_the_path(mini_root, tmp_path):
    root = tmp_path / "dimo"
    shutil.copytree(mini_root, root)
    dataset = open_dimo(root, "real")
    root.rename(tmp_path / "moved")  # the run's process has the data, the workers' path has none
    with pytest.raises(DatasetError, match=f"node .* cannot open the data at {root}.*same path"):
        next(ray_scenes(request(root, tmp_path / OUT, executor="ray", workers=1), dataset.scene_keys))


def test_more_workers_than_the_clusters_cpus_are_refused(mini_root, tmp_path, capsys):
    argv = ["run", "--heatmaps", "oracle", "--dataset", "dimo", "--data-root", str(mini_root), "--out",
            str(tmp_path / OUT), "--no-progress", "--executor", "ray", "--workers", "3"]  # fmt: skip
    assert main(argv) == 2
    assert "--workers: --workers 3: the Ray cluster has 2 CPUs" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_without_ray_the_executor_says_how_to_install_it(mini_root, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    argv = ["run", "--heatmaps", "oracle", "--dataset", "dimo", "--data-root", str(mini_root), "--out",
            str(tmp_path / OUT), "--no-progress", "--executor", "ray"]  # fmt: skip
    assert main(argv) == 2
    assert (
        '--executor: --executor ray needs Ray, which is not installed: pip install -e ".[ray]"'
        in capsys.readouterr().err
    )


@pytest.mark.parametrize(("address", "message"), [("127.0.0.1:1", "cannot reach a Ray head at 127.0.0.1:1"),
                                                  ("nohost", "expected auto or HOST:PORT")])  # fmt: skip
def test_an_address_that_does_not_answer_is_one_error(address, message):
    with pytest.raises(ConfigError, match=message) as caught:
        cluster.check_address(address)
    assert caught.value.field == "--address"


def test_an_address_without_ray_or_ray_options_without_ray_are_refused(tmp_path):
    with pytest.raises(ConfigError, match="add --executor ray"):
        run(request(Path("nowhere"), tmp_path / OUT, address="auto"))
    with pytest.raises(ConfigError, match="each Ray actor has one thread"):
        run(request(Path("nowhere"), tmp_path / OUT, executor="ray", threads=2))


def test_the_actors_get_absolute_paths_and_find_the_shipped_weights_on_their_own_node(mini_root, tmp_path,
                                                                                        monkeypatch):  # fmt: skip
    from bop_cender.net.weights import shipped_weights_path
    from bop_cender.runner import resolve_weights

    monkeypatch.chdir(mini_root.parent)
    shipped = resolve_weights(request(Path(mini_root.name), tmp_path / OUT, heatmaps="net"))
    assert shipped.weights == str(shipped_weights_path("dimo"))
    sent = ray_executor._for_the_nodes(shipped)
    assert sent.data_root == str(mini_root.resolve()) and sent.weights is None  # each node resolves its own install's
    (tmp_path / "w.pt").write_bytes(b"")
    given = ray_executor._for_the_nodes(replace(shipped, weights="../" + tmp_path.name + "/w.pt"))
    assert given.weights == str((tmp_path / "w.pt").resolve())


class SlowToStart:
    """An actor that takes longer to build than the test allows (as one waiting for a CPU held by other work)."""

    def __init__(self) -> None:
        import time

        time.sleep(5)

    def hello(self) -> cluster.WorkerHello:
        return cluster.WorkerHello.here()


def test_workers_that_do_not_start_in_time_are_one_error_not_a_wait(monkeypatch):
    monkeypatch.setattr(cluster, "START_TIMEOUT_S", 0.5)
    actors = cluster.start_actors(SlowToStart, 1)
    try:
        with pytest.raises(ConfigError, match=r"--workers: 1 Ray workers asked for, not all started after 0 s"):
            cluster.check_started(actors)
    finally:
        cluster.stop_actors(actors)
