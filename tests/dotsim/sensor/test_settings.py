"""dotsim/sensor/settings.py: the config's [sensor] at a render scale, and the [sensor] a scene.json
records, read back."""

from __future__ import annotations

import dataclasses
import doctest

import pytest

from dotsim.config_schema import ConfigError
from dotsim.sensor import settings
from dotsim.sensor.settings import SensorConfig, SensorSpec, recorded_sensor, sensor_noise


def test_doctests():
    result = doctest.testmod(settings)
    assert result.attempted > 0 and result.failed == 0


def test_at_scale_keeps_every_config_value_and_adds_the_scale():
    config = SensorConfig(exposure="fixed", gain=2.5, blur_sigma=1.5, bit_depth=12, speckle_contrast=0.3)
    scene = config.at_scale(0.25)
    assert isinstance(scene, SensorSpec) and scene.pixel_scale == 0.25
    assert {f.name: getattr(scene, f.name) for f in dataclasses.fields(SensorConfig)} == config.to_dict()
    assert scene.at_scale(0.5) == dataclasses.replace(scene, pixel_scale=0.5)
    with pytest.raises(ConfigError, match=r"^SensorSpec.pixel_scale = 0.01: out of range"):
        config.at_scale(0.01)


def test_a_recorded_table_reads_back_with_defaults_and_without_unknown_keys():
    meta = {"config": {"sensor": {"read_noise": 0.002, "shot_noise": 0.03, "later_key": True}}}
    assert recorded_sensor(meta) == meta["config"]["sensor"]
    sensor = SensorConfig.from_recorded(recorded_sensor(meta))
    assert sensor == dataclasses.replace(SensorConfig(), read_noise=0.002, shot_noise=0.03)
    assert SensorConfig.from_recorded(None) == SensorConfig()
    assert sensor_noise(meta) is None  # no bit_depth recorded: the noise of the stored image is unknown
    with pytest.raises(ConfigError, match=r"SensorConfig.read_noise = 2"):
        SensorConfig.from_recorded({"read_noise": 2})
