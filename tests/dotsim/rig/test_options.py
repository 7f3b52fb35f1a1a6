"""dotsim.rig.options: `--rig SPEC` and `--camera-file FILE` as every command reads them, and the check
of a config's [rig] settings."""

import doctest

import pytest

from dotsim.config_schema import ConfigError
from dotsim.rig import options
from dotsim.rig.config import RigConfig
from dotsim.rig.options import checked_rig, with_rig_options
from dotsim.rig.presets import get_preset


def test_the_docstring_examples():
    result = doctest.testmod(options)
    assert result.attempted > 0 and result.failed == 0


def test_a_stereo_pair_asked_of_a_rig_without_one_names_the_config_and_the_options():
    with pytest.raises(ConfigError, match=r"^gen.toml: \[rig\] stereo = true: rig 'kinect_v1' has no "
                                          r"second IR camera .*, or stereo = false$"):
        checked_rig(RigConfig(preset="kinect_v1", stereo=True), "gen.toml")
    with pytest.raises(ConfigError, match=r"^--rig kinect_v1: gen.toml: \[rig\] stereo = true: "):
        with_rig_options(RigConfig(stereo=True), "gen.toml", "kinect_v1")


def test_options_replace_the_preset_and_keep_the_other_keys():
    settings, calibrated = with_rig_options(RigConfig(scale=0.5, max_depth=7.0), "gen.toml", "realsense_d435")
    assert (settings.preset, settings.scale, settings.max_depth) == ("realsense_d435", 0.5, 7.0)
    assert calibrated.rig.camera == get_preset("realsense_d435").camera.scaled(0.5)
    assert calibrated.rig.max_depth == 7.0
