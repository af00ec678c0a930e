"""``--set`` on the config's sections: dotted paths at any depth, old names refused with the new one, removed
options refused with where their figures are, and ``--preset paper``."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from bop_cender.errors import ConfigError
from bop_cender.method import CenDerNetConfig
from bop_cender.pose.config import PRESETS, NelderMead, PoseConfig
from bop_cender.pose.config_names import FIGURES, REMOVED, RENAMED
from bop_cender.settings import apply_setting, setting_names

ROOT = Path(__file__).resolve().parents[1]


def _leaf(config: object, path: str) -> object:
    for part in path.split("."):
        config = getattr(config, part)
    return config


def test_a_setting_reaches_any_depth_and_leaves_the_rest():
    base = CenDerNetConfig.for_dataset("dimo")
    c = base.with_settings(["poses.candidates.n=500", "poses.refine.nelder_mead.maxfev=90", "centers.d_c=30"])
    assert c.poses.candidates.n == 500 and c.poses.refine.nelder_mead.maxfev == 90 and c.centers.d_c == 30.0
    assert c.poses.screen.nelder_mead == base.poses.screen.nelder_mead  # another section's Nelder-Mead untouched
    assert dataclasses.replace(c.poses.candidates, n=2000) == base.poses.candidates
    assert c.with_settings(["poses.network.t_b=0.4"]).poses.network.t_b == 0.4


def test_every_leaf_setting_can_be_set_by_its_path():
    """Each leaf of the tree, set to its own value through its dotted path, gives the same config back."""
    config = CenDerNetConfig.for_dataset("dimo")
    names = setting_names(config)
    assert "poses.scene_polish.nelder_mead.maxfev" in names and "poses.candidates" not in names
    for name in names:
        if name == "preset":
            continue
        value = _leaf(config, name)
        text = "none" if value is None else str(value).lower() if isinstance(value, bool) else repr(value)
        assert config.with_settings([f"{name}={text.strip(chr(39))}"]) == config, name


@pytest.mark.parametrize("old", sorted(RENAMED))
def test_every_old_name_is_one_error_giving_the_new_one(old):
    new = RENAMED[old]
    with pytest.raises(ConfigError, match=rf"--set: poses\.{old} was renamed poses\.{new} "):
        CenDerNetConfig.for_dataset("dimo").with_settings([f"poses.{old}=1"])
    assert f"poses.{new}" in setting_names(CenDerNetConfig())  # the new name exists


def test_the_old_names_message_reads_as_the_issue_asks():
    with pytest.raises(ConfigError) as caught:
        CenDerNetConfig().with_settings(["poses.scene_polish_maxfev=0"])
    assert str(caught.value).startswith(
        "--set: poses.scene_polish_maxfev was renamed poses.scene_polish.nelder_mead.maxfev"
    )


@pytest.mark.parametrize("name", sorted(REMOVED))
def test_a_removed_option_is_one_error_saying_where_its_figures_are(name):
    with pytest.raises(ConfigError, match=rf"poses\.{name} was removed: .*figures: results/accuracy/README\.md"):
        CenDerNetConfig().with_settings([f"poses.{name}=1"])
    assert not hasattr(PoseConfig(), name)


def test_the_figures_of_the_removed_options_are_where_the_errors_say():
    readme = (ROOT / "results" / "accuracy" / "README.md").read_text()
    section = FIGURES.split('"')[1]
    assert f"## {section}" in readme
    for name in REMOVED:
        assert f"`{name}`" in readme.split(f"## {section}")[1], name


def test_unknown_paths_sections_and_bad_values_are_one_error_each():
    c = CenDerNetConfig()
    with pytest.raises(ConfigError, match="unknown setting 'poses.candidates.bogus'; known: .*poses.candidates.n"):
        c.with_settings(["poses.candidates.bogus=1"])
    with pytest.raises(ConfigError, match="unknown setting 'poses.t_b.x'"):
        c.with_settings(["poses.t_b.x=1"])
    with pytest.raises(ConfigError, match="poses.refine is a section; set one of its fields: poses.refine.rot"):
        c.with_settings(["poses.refine=1"])
    with pytest.raises(ConfigError, match="poses.candidates.n: expected a int, got '1.5'"):
        c.with_settings(["poses.candidates.n=1.5"])
    with pytest.raises(ConfigError, match="poses.refine.nelder_mead.xatol: expected a number > 0"):
        c.with_settings(["poses.refine.nelder_mead.xatol=0"])
    assert c.with_settings(["poses.scene_polish.nelder_mead.xatol=0"]).poses.scene_polish.nelder_mead.xatol == 0
    assert c.with_settings(["poses.screen.nelder_mead.maxfev=0"]).poses.screen.nelder_mead.maxfev == 0
    with pytest.raises(ConfigError, match="preset is chosen before any setting"):
        c.with_settings(["preset=paper"])


def test_a_section_of_the_wrong_type_is_refused():
    with pytest.raises(ConfigError, match="poses.refine.nelder_mead: expected a NelderMead"):
        PoseConfig(refine=dataclasses.replace(PoseConfig().refine, nelder_mead=3))
    with pytest.raises(ConfigError, match="poses.screen.nelder_mead.maxfev: expected an integer >= 0"):
        PoseConfig(screen=dataclasses.replace(PoseConfig().screen, nelder_mead=NelderMead(maxfev=-1)))


def test_the_paper_preset_is_the_papers_stage_3_and_is_recorded():
    """``--preset paper``: one sweep, no scene polish, no centre term, no screen (the four settings of the eighteenth
    session's "the paper's stage 3" row), everything else as ours; the preset's name goes into the sidecar."""
    ours, paper = CenDerNetConfig.for_dataset("dimo"), CenDerNetConfig.for_dataset("dimo", "paper")
    old_flags = ["poses.sweeps.passes=1", "poses.scene_polish.nelder_mead.maxfev=0", "poses.center_weight=0",
                 "poses.screen.starts=0"]  # fmt: skip
    assert dataclasses.replace(paper, preset="ours") == ours.with_settings(old_flags)
    assert (paper.poses.sweeps.passes, paper.poses.scene_polish.nelder_mead.maxfev) == (1, 0)
    assert (paper.poses.center_weight, paper.poses.screen.starts) == (0.0, 0)
    assert paper.as_dict()["preset"] == "paper" and ours.as_dict()["preset"] == "ours"
    assert paper.with_settings(["poses.sweeps.passes=2"]).poses.sweeps.passes == 2  # --set after the preset
    tless = CenDerNetConfig.for_dataset("tless", "paper")
    assert tless.poses == paper.poses and tless.targets != paper.targets
    with pytest.raises(ConfigError, match="unknown preset 'best'; known: ours, paper"):
        CenDerNetConfig.for_dataset("dimo", "best")
    assert set(PRESETS) == {"ours", "paper"}


def test_the_network_section_overrides_only_where_set():
    config = PoseConfig()
    net = config.for_network_centers()
    assert (net.candidates.translation_sigma_mm, net.refine.translation_bound_mm, net.scene_polish.passes) == (
        10,
        30,
        1,
    )
    assert net.candidates.n == config.candidates.n and net.network == config.network
    same = apply_setting(apply_setting(config, "network.translation_sigma_mm=none"), "network.scene_polish_passes=none")
    net = same.for_network_centers()
    assert (net.candidates.translation_sigma_mm, net.refine.translation_bound_mm, net.scene_polish.passes) == (5, 30, 2)


def test_run_builds_its_config_from_the_preset_then_its_options_then_set():
    from bop_cender.cli.app import build_parser
    from bop_cender.cli.run import run_config

    def config_of(*argv: str) -> CenDerNetConfig:
        return run_config(build_parser().parse_args(["run", "--dataset", "dimo", *argv]))

    assert config_of() == CenDerNetConfig.for_dataset("dimo")
    paper = config_of("--preset", "paper", "--candidates", "500", "--set", "poses.sweeps.passes=2", "--seed", "3")
    assert paper.preset == "paper" and paper.poses.center_weight == 0.0 and paper.poses.screen.starts == 0
    assert (paper.poses.candidates.n, paper.poses.sweeps.passes, paper.poses.seed) == (500, 2, 3)
    assert config_of("--no-occlusion", "--set", "poses.occlusion=true").poses.occlusion is True  # --set last
    with pytest.raises(ConfigError, match="--top-k: refines the best 9"):
        config_of("--top-k", "9", "--candidates", "5")
    with pytest.raises(ConfigError, match="poses.passes was renamed poses.sweeps.passes"):
        config_of("--set", "poses.passes=1")
    with pytest.raises(SystemExit):
        config_of("--preset", "best")


@pytest.mark.parametrize("old", ["nm_initial_rotation_rad", "nm_initial_translation_mm", "nm_xatol", "nm_fatol"])
def test_an_old_name_that_drove_several_runs_says_which_others_it_set(old) -> None:
    """Before the sections the refinement's Nelder-Mead settings also drove the screen's (and the initial simplex the
    scene polish's, at a quarter): following the rename alone would change one run of three, silently."""
    with pytest.raises(ConfigError, match=rf"poses\.{old} was renamed .*; it also set poses\.screen\.nelder_mead\."):
        CenDerNetConfig.for_dataset("dimo").with_settings([f"poses.{old}=0.1"])
    with pytest.raises(ConfigError) as caught:
        CenDerNetConfig.for_dataset("dimo").with_settings(["poses.nm_maxfev=10"])
    assert "also" not in str(caught.value)  # the screen and the polish had maxfevs of their own
