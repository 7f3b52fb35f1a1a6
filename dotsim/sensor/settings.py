"""What a sensor is set to: the config's [sensor] table (SensorConfig), one scene's sensor at its
render scale (SensorSpec, what a SceneSpec holds), and the [sensor] a scene.json records, read
back (recorded_sensor, sensor_noise).

Needs only the standard library and dotsim.config_schema, so Blender's own Python can import it
with the SceneSpec (generator/scene_spec.py); the model that applies these settings is
dotsim/sensor/model.py.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from dotsim.config_schema import Checked, record_from_dict, setting

EXPOSURES = ("fixed", "auto")


@dataclass(frozen=True)
class SensorConfig(Checked):
    """The IR sensor as a config sets it: the config's [sensor] table (docs/CONFIG.md), one for every
    scene of a run; sizes in full-resolution sensor pixels. A scene's SceneSpec holds it at the
    render scale (at_scale: a SensorSpec)."""
    exposure: str = setting("auto", "fixed: ir = gain * signal; auto: scale so the auto_percentile of the"
                            " signal maps to auto_target (as GigaDepth's renders)", choices=EXPOSURES)
    gain: float = setting(1.0, "signal multiplier in fixed exposure", low=0.0, high=1e6, low_open=True)
    auto_percentile: float = setting(99.0, "percentile of the signal used by auto exposure", low=50.0,
                                     high=100.0)
    auto_target: float = setting(0.8, "level (fraction of full scale) the percentile maps to", low=0.0,
                                 high=1.0, low_open=True)
    bloom_threshold: float = setting(0.9, "level above which light blooms (fraction of full scale)",
                                     low=0.0, high=10.0)
    bloom_strength: float = setting(0.2, "share of the over-threshold light spread into the bloom",
                                    low=0.0, high=10.0)
    bloom_sigma: float = setting(4.0, "bloom spread, full-resolution px", low=0.0, high=100.0)
    blur_sigma: float = setting(0.5, "optical blur, full-resolution px (0 = none)", low=0.0, high=20.0)
    shot_noise: float = setting(0.01, "shot-noise standard deviation at full-scale signal; variance "
                                "grows linearly with the signal", low=0.0, high=1.0)
    read_noise: float = setting(0.003, "signal-independent read-noise standard deviation (full scale = 1)",
                                low=0.0, high=1.0)
    bit_depth: int = setting(10, "sensor bit depth: ir is quantised to 2**bit_depth levels", low=1,
                             high=16)
    speckle_contrast: float = setting(0.0, "laser speckle on the projector's direct light: standard "
                                      "deviation of its factor (mean 1; 0 = off, 1 = fully developed "
                                      "speckle); fixed "
                                      "for a scene and pose, another for another pose "
                                      "(docs/CONFIG_GUIDE.md \"Laser speckle\")", low=0.0, high=1.0)
    speckle_grain: float = setting(2.0, "speckle grain: full width at half maximum of the speckle's "
                                   "intensity autocorrelation, full-resolution px", low=0.0, high=100.0,
                                   low_open=True)
    projector_aperture: float = setting(0.0, "the projector's aperture, m (its lens's diameter; a "
                                        "collimated beam's through a diffractive element): the projector's "
                                        "defocus widens its dots away from projector_focus (thin lens: blur "
                                        "circle angular diameter = aperture x abs(1/depth - "
                     "1/projector_focus); "
                                        "docs/CONFIG_GUIDE.md \"Dot size\"); 0 = a pinhole, no defocus",
                                        low=0.0, high=0.1)
    projector_focus: float = setting(0.0, "the distance the projector is focused at, m; 0 = at infinity "
                                     "(a collimated beam through a diffractive element)", low=0.0, high=100.0)


    def at_scale(self, pixel_scale: float) -> SensorSpec:
        """This sensor in a render `pixel_scale` times the full sensor resolution (the config's [rig]
        scale).

        >>> SensorConfig(read_noise=0.002).at_scale(0.5).pixel_scale
        0.5
        """
        return SensorSpec(**{f.name: getattr(self, f.name) for f in fields(SensorConfig)},
                              pixel_scale=pixel_scale)

    @classmethod
    def from_recorded(cls, table: dict | None) -> SensorConfig:
        """The sensor of a [sensor] table as a scene.json records it (recorded_sensor): keys this
        version does not know are left out, keys the table lacks take their defaults; ConfigError
        naming a value out of its bounds.

        >>> SensorConfig.from_recorded({"read_noise": 0.002, "a_later_key": 1}).read_noise
        0.002
        """
        return cls(**{k: v for k, v in (table or {}).items() if k in cls.__dataclass_fields__})


@dataclass(frozen=True)
class SensorSpec(SensorConfig):
    """One scene's sensor, as its SceneSpec records it: the config's [sensor] (SensorConfig) and the
    render scale its pixel sizes are taken at (pixel_scale); the sensor model
    (dotsim/sensor/model.py) applies it."""
    pixel_scale: float = setting(1.0, "render resolution over the full sensor resolution (the config's "
                                 "[rig] scale; bloom, blur and speckle sizes are full-resolution px)",
                                 low=0.02, high=1.0)

    @classmethod
    def from_dict(cls, d: Any, where: str) -> SensorSpec:
        """Specs from before the speckle and defocus keys read as without speckle and defocus."""
        return record_from_dict(cls, d, where, optional=("speckle_contrast", "speckle_grain",
                                                           "projector_aperture", "projector_focus"))


def recorded_sensor(scene_meta: dict) -> dict | None:
    """The [sensor] table a scene's scene.json records (its config's), or None where it records none
    (real captures).

    >>> recorded_sensor({"config": {"sensor": {"read_noise": 0.003}}})
    {'read_noise': 0.003}
    >>> recorded_sensor({}) is None
    True
    """
    return scene_meta.get("config", {}).get("sensor")


def sensor_noise(scene_meta: dict) -> dict | None:
    """read_noise, shot_noise and bit_depth of the sensor a scene was rendered with (scene.json's
    config [sensor]), or None where the scene records none (then nothing can be said).

    >>> sensor_noise({"config": {"sensor": {"read_noise": 0.003, "shot_noise": 0.01, "bit_depth": 10}}})
    {'read_noise': 0.003, 'shot_noise': 0.01, 'bit_depth': 10}
    >>> sensor_noise({}) is None
    True
    """
    sensor = recorded_sensor(scene_meta)
    if not sensor or not {"read_noise", "shot_noise", "bit_depth"} <= set(sensor):
        return None
    return {k: sensor[k] for k in ("read_noise", "shot_noise", "bit_depth")}
