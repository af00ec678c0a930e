"""Result file names against the run they hold: the default name of a split folder, contradictions, and the split
``score`` opens from a sidecar (the folder) or from a name (split and split type)."""

from __future__ import annotations

import pytest

from bop_cender.eval.score_file import choose_data
from bop_cender.results.bop_csv import write_bop_results
from bop_cender.results.files import (
    default_result_filename,
    name_contradiction,
    parse_result_filename,
    write_run_sidecar,
)


def test_the_default_name_of_an_underscore_split_is_bops_split_and_type() -> None:
    assert default_result_filename("cendernet-net", "tless", "test") == "cendernet-net_tless-test.csv"
    assert default_result_filename("cendernet-net", "lmo", "train_pbr") == "cendernet-net_lmo-train-pbr.csv"
    name = parse_result_filename(default_result_filename("m", "bop", "test_primesense"))
    assert (name.split, name.split_type) == ("test", "primesense")
    assert name_contradiction(name, "bop", "test_primesense") is None


@pytest.mark.parametrize(
    "file_name, dataset, split, problem",
    [
        ("m_dimo-real.csv", "dimo", "real", None),
        ("m_lmo-test.csv", "bop", "test", None),  # a run on --dataset bop agrees with any dataset part
        ("m_dimo-sim.csv", "dimo", "real", "split 'sim'"),
        ("m_tless-real.csv", "dimo", "real", "dataset 'tless'"),
        ("m_tless-test-kinect.csv", "tless", "test", "split 'test-kinect'"),  # names another folder
        ("m_tless-test-kinect.csv", "tless", "test_kinect", None),
        ("m_tless-train_pbr.csv", "tless", "train_pbr", None),  # the default name before BOP's naming
    ],
)
def test_a_name_contradicts_the_run_only_where_it_names_other_data(file_name, dataset, split, problem) -> None:
    found = name_contradiction(parse_result_filename(file_name), dataset, split)
    assert found is None if problem is None else problem in found


def test_score_opens_the_sidecars_split_folder_without_the_names_split_type(tmp_path) -> None:
    """A sidecar's split is the folder (``test_primesense``): the name's split type must not be added to it again."""
    csv_path = tmp_path / "m_lmo-test-primesense.csv"
    write_bop_results(csv_path, [])
    write_run_sidecar(csv_path, tmp_path, "bop", "test_primesense", {"n_views": None}, seed=0)
    request = choose_data(csv_path).request
    assert (request.split, request.split_type) == ("test_primesense", None)
    bare = tmp_path / "n_lmo-test-primesense.csv"  # no sidecar: the split and its type come from the name
    write_bop_results(bare, [])
    request = choose_data(bare, data_root=tmp_path).request
    assert (request.split, request.split_type) == ("test", "primesense")


@pytest.mark.parametrize("views", ["abc", [1], 2.7, 0, True])
def test_a_sidecars_bad_view_count_is_one_error_naming_it(tmp_path, views) -> None:
    from bop_cender.errors import ResultsError

    csv_path = tmp_path / "m_dimo-real.csv"
    write_bop_results(csv_path, [])
    write_run_sidecar(csv_path, tmp_path, "dimo", "real", {"n_views": views}, seed=0)
    with pytest.raises(ResultsError, match="m_dimo-real.json: selection.n_views: expected a positive integer"):
        choose_data(csv_path)
    assert choose_data(csv_path, n_views=3).request.n_views == 3  # the option decides


def test_score_refuses_a_malformed_failed_scenes_record(tmp_path) -> None:
    from bop_cender.errors import ResultsError

    csv_path = tmp_path / "m_dimo-real.csv"
    write_bop_results(csv_path, [])
    write_run_sidecar(csv_path, tmp_path, "dimo", "real", {}, seed=0, extra={"failed_scenes": ["000001"]})
    with pytest.raises(ResultsError, match="extra.failed_scenes: expected an object of scene keys"):
        choose_data(csv_path)
