"""dotsim.rig.config: a generator config's [rig] table, declared in the rig package."""

import doctest

import pytest

from dotsim.config_schema import ConfigError, bounds_of
from dotsim.rig import config
from dotsim.rig.config import RigConfig
from dotsim.rig.geometry import Rig


def test_the_docstring_example():
    result = doctest.testmod(config)
    assert result.attempted > 0 and result.failed == 0


def test_max_depth_has_the_rigs_bounds():
    assert bounds_of(RigConfig, "max_depth") == bounds_of(Rig, "max_depth")
    with pytest.raises(ConfigError, match=r"^RigConfig.max_depth = 0.1: out of range; allowed: a number, "
                                          r"0.5 <= x <= 1000$"):
        RigConfig(max_depth=0.1)
