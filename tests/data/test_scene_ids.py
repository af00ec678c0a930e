import pytest

from bop_cender.data.scene_ids import int_to_scene_folder, is_suffixed, scene_folder_to_int


@pytest.mark.parametrize(
    ("folder", "value", "suffixed"),
    [("000123", 123, False), ("000123_17", 12317, True), ("000000_00", 0, True), ("000599_70", 59970, True)],
)
def test_round_trip(folder, value, suffixed):
    assert scene_folder_to_int(folder) == value
    assert int_to_scene_folder(value, suffixed) == folder
    assert is_suffixed(folder) == suffixed


@pytest.mark.parametrize("bad", ["abc", "000123_1", "000123_170", "", "12_ab", "-1"])
def test_rejects_other_names(bad):
    with pytest.raises(ValueError, match="neither"):
        scene_folder_to_int(bad)


def test_negative_int_rejected():
    with pytest.raises(ValueError):
        int_to_scene_folder(-3, suffixed=False)
