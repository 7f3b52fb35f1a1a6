"""The typed SceneSpec: JSON round trip, errors that name the field and value, and make_frame
reading the spec's own sensor-model and mask parameters."""

from __future__ import annotations

import copy
import dataclasses
import json
from dataclasses import replace

import numpy as np
import pytest

from dotsim import config_schema
from dotsim.config_schema import ConfigError
from dotsim.device_depth import DeviceDepthConfig
from dotsim.rig.config import RigConfig
from dotsim.sensor.model import SensorStreams
from dotsim.sensor.settings import SensorSpec
from generator.config import Config, LightingConfig, SceneConfig, config_from_dict
from generator.post_render import make_frame
from generator.sample_scene import SceneResources, TextureAsset, sample_scene_spec
from generator.scene_spec import (
    FRAMES_PER_SCENE,
    MaskParams,
    Material,
    PointLight,
    PrimitiveMesh,
    SceneRenderSettings,
    SceneSpec,
    Texture,
    camera_views,
)

RESOURCES = SceneResources("/data/pattern.png", "ab" * 32, (TextureAsset("/data/t0.png"),))


def sampled(**overrides) -> SceneSpec:
    return sample_scene_spec(config_from_dict(overrides), 2, 5, "train", RESOURCES)


def test_json_round_trip_gives_the_same_typed_spec():
    spec = sampled(rig={"scale": 0.1})
    again = SceneSpec.from_dict(json.loads(json.dumps(spec.to_dict())))
    assert again == spec and again is not spec
    assert len(again.poses) == FRAMES_PER_SCENE and again.poses[2].shape == (4, 4)
    np.testing.assert_array_equal(again.poses[3], spec.poses[3])
    assert any(isinstance(o.material.texture, Texture) for o in again.objects)
    assert all(isinstance(o.mesh, PrimitiveMesh) for o in again.objects)
    assert all(isinstance(light, PointLight) for light in again.lights)
    assert again.rig == spec.rig and again.sensor == spec.sensor and again.masks == spec.masks
    assert replace(again, world_strength=again.world_strength + 1) != spec


@pytest.mark.parametrize("table, record, added", [
    ("render", SceneRenderSettings, {"seed"}), ("sensor", SensorSpec, {"pixel_scale"}),
    ("masks", MaskParams, set()), ("device_depth", DeviceDepthConfig, set())])
def test_the_spec_carries_the_configs_own_settings(table, record, added):
    """Bounds agree by construction: the spec's Cycles, sensor and mask records are the config's
    [render], [sensor] and [masks] tables (or derive from them, adding only what the sampler adds),
    so every setting they share is one field object, with one rule."""
    declared = config_schema.tables(Config)[table]
    assert issubclass(record, declared)
    config_fields = {f.name: f for f in dataclasses.fields(declared)}
    spec_fields = {f.name: f for f in dataclasses.fields(record)}
    assert set(spec_fields) == set(config_fields) | added
    for name, field in config_fields.items():
        assert spec_fields[name] is field and spec_fields[name].metadata is field.metadata
    # and a sampled spec records the config's table, plus the sampler's additions
    recorded = sampled().to_dict()[table]
    assert {key: recorded[key] for key in config_fields} == Config().to_dict()[table]
    assert set(recorded) == set(config_fields) | added


def test_a_spec_built_in_code_is_checked_like_one_read_from_json():
    spec = sampled()
    with pytest.raises(ConfigError, match=r"^SensorSpec.auto_percentile = 20: out of range; allowed: a "
                       r"number, 50 <= x <= 100$"):
        replace(spec, sensor=replace(spec.sensor, auto_percentile=20))
    with pytest.raises(ConfigError, match=r"^SceneSpec.world_strength = -1.0: out of range"):
        replace(spec, world_strength=-1.0)
    with pytest.raises(ConfigError, match=r"^Material.albedo = -0.5: out of range"):
        replace(spec.objects[0].material, albedo=-0.5)
    with pytest.raises(ConfigError, match=r"^SceneRenderSettings.samples = 5000: out of range"):
        replace(spec.render, samples=5000)
    with pytest.raises(ConfigError, match=r"^SceneSpec.poses = \(\): not a non-empty list"):
        replace(spec, poses=())
    with pytest.raises(ConfigError, match=r"^PrimitiveMesh.size = \[1.0, 2.0\]: wrong type"):
        PrimitiveMesh(shape="box", size=(1.0, 2.0))
    # numbers are normalised as from_dict does: an int where a float is declared becomes a float
    assert type(replace(spec, world_strength=1).world_strength) is float


def _set(path: list, value):
    def change(d: dict) -> None:
        target = d
        for key in path[:-1]:
            target = target[key]
        if value is _DELETE:
            del target[path[-1]]
        else:
            target[path[-1]] = value
    return change


_DELETE = object()


def test_the_device_depth_engine_comes_from_the_config_and_older_specs_have_it_off():
    spec = sampled(device_depth={"engine": "structured_light", "reference_distance": 1.5})
    again = SceneSpec.from_dict(json.loads(json.dumps(spec.to_dict())))
    assert again.device_depth == spec.device_depth and again.device_depth.reference_distance == 1.5
    older = sampled().to_dict()
    del older["device_depth"]  # a spec written before the engine existed
    assert SceneSpec.from_dict(older).device_depth == DeviceDepthConfig() and not DeviceDepthConfig().on


def test_direct_light_comes_from_the_config_and_older_specs_read_as_separate():
    assert sampled().render.direct_light == "separate"
    assert sampled(render={"direct_light": "shared"}).render.direct_light == "shared"
    older = sampled().to_dict()
    del older["render"]["direct_light"]  # scene.json written before the setting existed
    assert SceneSpec.from_dict(older).render.direct_light == "separate"


@pytest.mark.parametrize("change, message", [
    (_set(["objects", 3, "material", "albedo"], -1),
     "objects[3].material.albedo = -1: out of range; allowed: a number, 0 <= x"),
    (_set(["masks"], _DELETE), "scene spec: masks is missing"),
    (_set(["colour"], 1), "scene spec: colour is not a field"),
    (_set(["render", "samples"], 0), "render.samples = 0: out of range; allowed: an integer, 1 <= x <= 4096"),
    (_set(["render", "samples"], 5000), "render.samples = 5000: out of range"),  # the config's bound
    (_set(["render", "device"], "TPU"), 'render.device = \'TPU\': not a valid choice (did you mean "GPU"?)'),
    (_set(["render", "direct_light"], "both"),
     'render.direct_light = \'both\': not a valid choice; allowed: one of "separate", "shared"'),
    (_set(["render", "colour"], 1), 'render: unknown key "colour"'),
    (_set(["poses", 1], [[1, 0], [0, 1]]), "poses[1] = [[1, 0], [0, 1]]: wrong type (expected a four-element "
     "array); allowed: a list of 4 lists of 4 numbers"),
    (_set(["poses", 0, 2, 3], float("inf")), "inf], [0.0, 0.0, 0.0, 1.0]]: not finite"),
    (_set(["poses"], []), "poses = []: not a non-empty list"),
    (_set(["lights"], [{"type": "SUN", "location": [0, 0, 0], "power": 1, "radius": 0}]),
     "lights[0].type = 'SUN': not a valid choice; allowed: one of \"POINT\""),
    (_set(["objects", 0, "mesh", "shape"], "pyramid"),
     "objects[0].mesh.shape = 'pyramid': not a valid choice"),
    (_set(["objects", 0, "mesh", "kind"], "cloud"),
     "objects[0].mesh.kind = 'cloud': not a valid choice; allowed: one of \"primitive\", \"asset\""),
    (_set(["objects", 1, "location"], [1.0, 2.0]),
     "objects[1].location = [1.0, 2.0]: wrong type (expected a three-element array)"),
    (_set(["objects", 2, "rotation_euler", 1], float("nan")),
     "objects[2].rotation_euler = [1.5707963267948966, nan, 0.0]: not finite"),
    (_set(["sensor", "bit_depth"], 17),
     "sensor.bit_depth = 17: out of range; allowed: an integer, 1 <= x <= 16"),
    (_set(["sensor", "auto_percentile"], 20), "sensor.auto_percentile = 20: out of range; allowed: a number, "
     "50 <= x <= 100"),  # the config's bound
    (_set(["sensor", "exposure"], "manual"), "sensor.exposure = 'manual': not a valid choice"),
    (_set(["masks", "edge_threshold"], 0.0),
     "masks.edge_threshold = 0.0: out of range; allowed: a number, 0 < x"),
    (_set(["masks", "edge_dilation"], 51), "masks.edge_dilation = 51: out of range"),  # the config's bound
    (_set(["projector", "power"], "bright"),
     "projector.power = 'bright': wrong type (str); allowed: a number, 0 <= x"),
    (_set(["split"], "val"), "split = 'val': not a valid choice; allowed: one of \"train\", \"test\""),
    (_set(["rig", "camera", "fx"], -3.0), "rig.camera.fx = -3.0: out of range; allowed: a number, 0 < x"),
    (_set(["pattern", "sha256"], _DELETE), "pattern.sha256 is missing"),
    (_set(["cameras", 0, "name"], "middle"), "cameras[0].name = 'middle': not a valid choice"),
    (_set(["cameras", 0, "translation"], [0.01, 0, 0]), "cameras = [{'name': 'left', 'intrinsics': "),
    (_set(["cameras"], []), "not the rig's cameras; allowed: the rig's camera (left: its intrinsics at"),
    (_set(["pattern", "sha256"], ""), "pattern.sha256 = '': empty; allowed: a non-empty string"),
])
def test_bad_fields_are_named_with_their_value(change, message):
    d = copy.deepcopy(sampled(rig={"scale": 0.1}).to_dict())
    d["objects"][5]["material"]["texture"] = {"path": "/t.png", "scale": 2.0, "contrast": 0.5}
    SceneSpec.from_dict(d)  # valid before the change
    change(d)
    with pytest.raises(ValueError, match="scene spec: ") as error:
        SceneSpec.from_dict(d)
    assert message in str(error.value)


def test_cameras_are_the_rigs_own_and_its_second_and_older_specs_read_with_its_own():
    """The cameras a frame is rendered from are data: the rig's camera at its origin and, on a rig with
    a second camera (Structure Core's, 0.07501 m along x), that one; a spec without the key (from
    before it) has the rig's own alone."""
    spec = sampled(rig={"scale": 0.1})
    (left,) = spec.cameras
    assert (left.name, left.intrinsics, left.translation, left.suffix) == ("left", spec.rig.camera,
                                                                            (0.0, 0.0, 0.0), "")
    older = spec.to_dict()
    del older["cameras"]
    assert SceneSpec.from_dict(older) == spec
    pair = replace(spec, cameras=camera_views(spec.rig, second=True))
    right = pair.cameras[1]
    assert (right.name, right.translation, right.suffix) == ("right", (0.07501, 0.0, 0.0), "_right")
    assert SceneSpec.from_dict(json.loads(json.dumps(pair.to_dict()))) == pair
    pose = pair.poses[1]
    np.testing.assert_allclose(right.pose(pose)[:3, 3], pose[:3, 3] + 0.07501 * pose[:3, 0])
    np.testing.assert_array_equal(left.pose(pose), pose)  # the rig's own camera is the rig's pose
    kinect = sampled(rig={"preset": "kinect_v1", "scale": 0.1}).rig
    with pytest.raises(ConfigError, match="rig 'kinect_v1' has no second IR camera"):
        camera_views(kinect, second=True)
    with pytest.raises(ConfigError, match="SceneSpec.cameras = .*not the rig's cameras"):
        replace(spec, rig=kinect)  # Structure Core's camera on a Kinect


def test_texture_fields_are_checked_where_they_are():
    d = sampled(rig={"scale": 0.1}).to_dict()
    d["objects"][4]["material"]["texture"] = {"path": "/t.png", "scale": 2.0, "contrast": -0.5}
    with pytest.raises(ValueError, match=r"objects\[4\]\.material\.texture\.contrast = -0.5: out of range"):
        SceneSpec.from_dict(d)


def test_make_frame_uses_the_specs_sensor_and_mask_parameters():
    """make_frame takes no config: the bit depth, edge dilation and visibility margin come from the
    spec."""
    spec = sampled(rig={"scale": 0.05})
    h, w = spec.rig.camera.height, spec.rig.camera.width
    depth = np.full((h, w), 2.0, np.float32)
    depth[:, w // 2:] = 1.0  # one vertical depth edge
    raw = {"projector": np.full((h, w), 0.3, np.float32), "flood": np.ones((h, w), np.float32),
           "ambient": np.full((h, w), 0.05, np.float32), "depth": depth}
    raw["projector_direct"], raw["flood_direct"] = raw["projector"], raw["flood"]  # no bounced light
    coarse = replace(spec, sensor=replace(spec.sensor, bit_depth=3, shot_noise=0.0, read_noise=0.0),
                     masks=replace(spec.masks, edge_dilation=0))
    wide = replace(coarse, masks=replace(coarse.masks, edge_dilation=3))
    ir = make_frame(raw, coarse, [SensorStreams(np.random.default_rng(0))])["ir"].astype(np.float64)
    np.testing.assert_allclose(ir * 7, np.round(ir * 7), atol=1e-6)  # 2**3 - 1 levels
    narrow_edges = make_frame(raw, coarse, [SensorStreams(np.random.default_rng(0))])["edge"].sum(axis=1)
    wide_edges = make_frame(raw, wide, [SensorStreams(np.random.default_rng(0))])["edge"].sum(axis=1)
    assert np.all(wide_edges == narrow_edges + 6)  # dilation 3 widens the edge by 3 px each side
    # the visibility margin (noise sigmas a dot must stand out by) is the spec's too
    noisy = replace(spec, sensor=replace(spec.sensor, read_noise=0.05))
    strict = replace(noisy, masks=replace(noisy.masks, visibility_margin=100.0))  # the largest allowed
    assert make_frame(raw, noisy, [SensorStreams(np.random.default_rng(0))])["visibility"].all()
    assert not make_frame(raw, strict, [SensorStreams(np.random.default_rng(0))])["visibility"].any()


def test_spec_and_the_pure_blender_modules_import_with_numpy_alone():
    """Blender's own Python has bpy, numpy and the standard library: what run_in_blender.py needs
    besides bpy must import with nothing else (checked in a fresh interpreter)."""
    import ast
    import subprocess
    import sys
    from pathlib import Path

    code = ("import sys; import generator.scene_spec, generator.blender.geometry, "
            "generator.blender.pattern_filter, generator.blender.exr; "
            "print(sorted({m.split('.')[0] for m in sys.modules} - set(sys.stdlib_module_names)))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                          cwd=Path(__file__).resolve().parents[2])
    third_party = {name for name in ast.literal_eval(proc.stdout) if not name.startswith("_")}
    assert third_party <= {"numpy", "dotsim", "generator", "cython_runtime"}, third_party


# (config record, key, spec record, field): the config keys whose values a sampled spec carries.
CONFIG_TO_SPEC = [
    (SceneConfig, "albedo", Material, "albedo"),
    (SceneConfig, "roughness", Material, "roughness"),
    (SceneConfig, "glossy_roughness", Material, "roughness"),
    (SceneConfig, "specular", Material, "specular"),
    (SceneConfig, "glossy_specular", Material, "specular"),
    (SceneConfig, "texture_contrast", Texture, "contrast"),
    (LightingConfig, "world_strength", SceneSpec, "world_strength"),
    (LightingConfig, "light_power", PointLight, "power"),
    (LightingConfig, "light_radius", PointLight, "radius"),
    (LightingConfig, "projector_power", SceneSpec, "projector_power"),
    (RigConfig, "scale", SensorSpec, "pixel_scale"),
]
PROBES = (-1.0, -1e-9, 0.0, 1e-9, 0.0199, 0.02, 0.5, 1.0, 1.000001, 10.0, 10.00001, 100.0, 100.0001, 1e6,
          1.000001e6)


def _allowed(owner, name, value) -> bool:
    try:
        config_schema.check_field(owner, name, value, "probe")
    except ConfigError:
        return False
    return True


@pytest.mark.parametrize("config_record, key, spec_record, field", CONFIG_TO_SPEC)
def test_a_spec_allows_exactly_the_values_its_config_allows(config_record, key, spec_record, field):
    """A spec read from a file (the add-on, run_in_blender.py) is held to the config's bounds: every
    probe the config refuses, the spec refuses, and the other way round (a spec may switch its
    projector off: power 0, which a config never asks for)."""
    ranged = dataclasses.fields(config_record)[[f.name for f in dataclasses.fields(config_record)].index(key)]
    for value in PROBES:
        given = [value, value] if ranged.type == "FloatRange" else value
        config_ok = _allowed(config_record, key, given)
        spec_ok = _allowed(spec_record, field, value)
        if field == "projector_power" and value == 0.0:
            assert spec_ok and not config_ok
        else:
            assert config_ok == spec_ok, (key, value, config_ok, spec_ok)
