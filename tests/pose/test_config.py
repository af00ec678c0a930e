"""Stage 3's settings (``pose/config.py``): every section checked where it enters, and the dataset layouts."""

from __future__ import annotations

from dataclasses import asdict

import pytest

from bop_cender.errors import ConfigError
from bop_cender.method import CenDerNetConfig
from bop_cender.pose.config import NetworkSettings, PoseConfig


def test_an_unknown_named_setting_is_one_config_error_before_any_scene():
    with pytest.raises(ConfigError, match="poses.search_cost: expected one of edges, render"):
        CenDerNetConfig.for_dataset("dimo").with_settings(["poses.search_cost=bogus"])
    with pytest.raises(ConfigError, match="poses.search_cost"):
        PoseConfig(search_cost="median")
    with pytest.raises(ConfigError, match="poses.sweeps.passes: expected an integer >= 1"):
        CenDerNetConfig().with_settings(["poses.sweeps.passes=0"])


@pytest.mark.parametrize(
    "path",
    [
        "scene_polish.nelder_mead.maxfev",
        "scene_polish.margin_px",
        "scene_polish.nelder_mead.xatol",
        "scene_polish.nelder_mead.fatol",
        "center_weight",
        "screen.starts",
        "screen.nelder_mead.maxfev",
    ],
)
@pytest.mark.parametrize("value", ["-1", "nan"])
def test_a_negative_or_nan_stage3_setting_is_a_config_error(path, value):
    with pytest.raises(ConfigError, match=f"poses.{path}: expected"):
        CenDerNetConfig().with_settings([f"poses.{path}={value}"])


def test_the_search_screen_is_on_for_dimo_and_off_for_tless_layouts_unless_set():
    assert CenDerNetConfig.for_dataset("dimo").poses.screen.starts == PoseConfig().screen.starts == 8
    assert CenDerNetConfig.for_dataset("tless").poses.screen.starts == 0
    assert CenDerNetConfig.for_dataset("bop").poses.screen.starts == 0
    assert CenDerNetConfig.for_dataset("tless").with_settings(["poses.screen.starts=6"]).poses.screen.starts == 6
    tless, dimo = asdict(CenDerNetConfig.for_dataset("tless").poses), asdict(PoseConfig())
    assert {k: v for k, v in tless.items() if dimo[k] != v} == {"screen": {**dimo["screen"], "starts": 0}}


def test_bins_keep_the_screen_and_separate_their_starts_modulo_symmetries_unless_set():
    dimo = asdict(PoseConfig())
    for name in ("industrial", "ipd", "xyzibd", "itoddmv"):
        bins = CenDerNetConfig.for_dataset(name)
        assert bins.poses.screen.starts == 8 and bins.poses.candidates.symmetric_separation
        assert bins.targets == CenDerNetConfig.for_dataset("industrial").targets
        changed = {k: v for k, v in asdict(bins.poses).items() if dimo[k] != v}
        assert changed == {"candidates": {**dimo["candidates"], "symmetric_separation": True}}
    unset = CenDerNetConfig.for_dataset("ipd").with_settings(["poses.candidates.symmetric_separation=false"])
    assert not unset.poses.candidates.symmetric_separation
    assert not CenDerNetConfig.for_dataset("bop").poses.candidates.symmetric_separation


def test_the_curvature_thresholds_are_checked():
    with pytest.raises(ConfigError, match="poses.t_b: expected a number in"):
        PoseConfig(t_b=1.0)
    for bad in (-0.1, float("nan")):
        with pytest.raises(ConfigError, match="poses.network.t_b: expected a number in"):
            PoseConfig(network=NetworkSettings(t_b=bad))
    assert PoseConfig(network=NetworkSettings(t_b=0.5)).network.t_b == 0.5 and PoseConfig().network.t_b is None


def test_each_nelder_mead_run_has_its_own_settings():
    """One settings type for every Nelder-Mead run, each with its defaults: the refinement's, the screen's (30
    evaluations), the scene polish's (a quarter of the refinement's simplex, looser tolerances, 100 evaluations)."""
    config = PoseConfig()
    refine, screen, polish = config.refine.nelder_mead, config.screen.nelder_mead, config.scene_polish.nelder_mead
    assert (refine.maxfev, screen.maxfev, polish.maxfev) == (150, 30, 100)
    assert screen.initial_rotation_rad == refine.initial_rotation_rad and screen.xatol == refine.xatol
    assert polish.initial_rotation_rad == refine.initial_rotation_rad / 4
    assert polish.initial_translation_mm == refine.initial_translation_mm / 4
    assert (polish.xatol, polish.fatol) == (0.2, 0.005)
