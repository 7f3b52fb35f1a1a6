"""The post-render on hand-made raw passes (no Blender): radiance beyond float16's range saturates; the
laser speckle (on the projector's direct light only, fixed for a pose, off by default, a field of its
own for each camera), and the frame of a stereo pair (the right IR through the same sensor model at
the left frame's exposure with a noise stream of its own, and the stereo mask of a wall both cameras
see).

The speckle tests use a noise-free sensor (no read or shot noise, 16 bits, fixed gain 1, no blur or
bloom), so the stored ir is ambient + projector x speckle up to 16-bit rounding, and the speckle
factor can be read back.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dotsim.channels import rendered_channels, stored_channels
from dotsim.dataset.frames import encode_frame
from dotsim.rig.presets import get_preset
from dotsim.sensor.model import SensorStreams
from generator.blender.frame_recipe import RAW_PASSES
from generator.config import config_from_dict
from generator.post_render import frame_channels, make_frame, raw_pass_names
from generator.sample_scene import SceneResources, frame_streams, sample_scene_spec

RIG = get_preset("structure_core").scaled(0.1)
SHAPE = (RIG.camera.height, RIG.camera.width)


def noise(*seeds: int) -> list[SensorStreams]:
    """Noise streams of these seeds, one camera each, without speckle."""
    return [SensorStreams(np.random.default_rng(seed)) for seed in seeds]


def spec_with(**sensor):
    table = {"exposure": "fixed", "gain": 1.0, "bloom_strength": 0.0, "blur_sigma": 0.0, "read_noise": 0.0,
             "shot_noise": 0.0, "bit_depth": 16, **sensor}
    config = config_from_dict({"rig": {"scale": 0.1}, "sensor": table})
    spec = sample_scene_spec(config, 0, 0, "train", SceneResources("/p.png", "0" * 64))
    assert spec.rig == RIG and spec.sensor.pixel_scale == 0.1
    return spec


def raw_frame(ambient: float, direct: float, indirect: float = 0.0) -> dict:
    depth = np.full(SHAPE, 2.0, np.float32)
    flat = np.ones(SHAPE, np.float32)
    return {"projector": (direct + indirect) * flat, "flood": flat, "ambient": ambient * flat, "depth": depth,
            "projector_direct": direct * flat, "flood_direct": flat}


def test_speckle_multiplies_the_projectors_direct_light_and_stays_put_for_a_pose():
    spec = spec_with(speckle_contrast=0.5, speckle_grain=20.0)  # 2 render px at scale 0.1
    poses = spec.poses
    spec = replace(spec, poses=(poses[0], poses[0], poses[1], poses[2]))
    # ambient 0.03 and indirect projector light 0.02 unspeckled, direct light 0.1 x speckle
    frames = [make_frame(raw_frame(0.03, 0.1, 0.02), spec, frame_streams(0, spec, k)) for k in range(4)]
    factors = [(frame["ir"].astype(np.float64) - 0.05) / 0.1 for frame in frames]
    for factor in factors:
        # 16-bit rounding of ir / 0.1: at most 8e-5 off a factor of mean 1 and std 0.5
        assert factor.mean() == pytest.approx(1.0, abs=0.06) and factor.std() == pytest.approx(0.5, rel=0.15)
        assert factor.min() >= 0.5 - 1e-4
    np.testing.assert_array_equal(frames[0]["ir"], frames[1]["ir"])  # one pose: the same speckle
    assert np.corrcoef(factors[0].ravel(), factors[2].ravel())[0, 1] < 0.2  # another pose: another
    assert np.corrcoef(factors[2].ravel(), factors[3].ravel())[0, 1] < 0.2
    # without direct light nothing is speckled, and speckle off is the plain sum
    dark = make_frame(raw_frame(0.3, 0.0, 0.1), spec, frame_streams(0, spec, 0))
    np.testing.assert_allclose(dark["ir"], 0.4, atol=1e-5)
    plain = make_frame(raw_frame(0.2, 0.5), spec_with(), noise(0))
    np.testing.assert_allclose(plain["ir"], 0.7, atol=1e-5)


def test_speckle_needs_a_speckle_stream():
    spec = spec_with(speckle_contrast=0.5)
    with pytest.raises(ValueError, match=r"^scene 0 frame 7: the sensor has laser speckle "
                       r"\(speckle_contrast > 0\): every camera's SensorStreams needs a speckle stream$"):
        make_frame(raw_frame(0.2, 0.5), spec, noise(0), where="scene 0 frame 7")
    with pytest.raises(ValueError, match=r"^frame = 4: not a frame of scene 0; allowed: 0 to 3$"):
        frame_streams(0, spec, 4)


def stereo_spec(**sensor):
    config = config_from_dict({"rig": {"preset": "realsense_d415", "scale": 0.05, "stereo": True},
                               "sensor": sensor})
    return sample_scene_spec(config, 0, 0, "train", SceneResources("/p.png", "0" * 64))


def wall_passes(spec, right_gain: float = 1.0) -> dict[str, np.ndarray]:
    """Raw passes of both cameras of a wall 2 m away, lit everywhere but columns 30-32 (a shadow);
    the right camera's projector light `right_gain` times the left's."""
    camera = spec.rig.camera
    shape = (camera.height, camera.width)
    flood = np.ones(shape, np.float32)
    flood[:, 30:33] = 0.0
    projector = flood * np.random.default_rng(0).uniform(0.2, 1, shape).astype(np.float32)
    left = {"projector": projector, "flood": flood, "ambient": np.full(shape, 0.1, np.float32),
            "depth": np.full(shape, 2.0, np.float32), "projector_direct": projector, "flood_direct": flood}
    right = dict(left, projector=projector * np.float32(right_gain))
    return {**left, **{f"{name}_right": value for name, value in right.items()}}


def test_a_stereo_frame_has_the_declared_channels_and_the_right_ir_shares_the_exposure():
    """Without noise, equal light gives equal IR; with twice the projector light, the right IR's level
    per unit light is still the left's (the left frame's exposure: auto exposure of the right image
    alone would have darkened it)."""
    spec = stereo_spec(shot_noise=0.0, read_noise=0.0, bloom_strength=0.0, blur_sigma=0.0)
    assert raw_pass_names(spec) == RAW_PASSES + tuple(f"{name}_right" for name in RAW_PASSES)
    assert frame_channels(spec) == rendered_channels(stereo=True)
    frame = make_frame(wall_passes(spec), spec, noise(0, 1))
    assert tuple(frame) == stored_channels(rendered_channels(stereo=True))
    np.testing.assert_array_equal(frame["ir_right"], frame["ir"])
    passes = wall_passes(spec, right_gain=2.0)
    brighter = make_frame(passes, spec, noise(0, 1))
    np.testing.assert_array_equal(brighter["ir"], frame["ir"])
    left_light = passes["ambient"] + passes["projector"]
    right_light = passes["ambient_right"] + passes["projector_right"]
    unclipped = (brighter["ir_right"] < 1) & (left_light > 0.3)
    gain_left = frame["ir"][unclipped] / left_light[unclipped]
    gain_right = brighter["ir_right"][unclipped] / right_light[unclipped]
    np.testing.assert_allclose(gain_right, gain_left, rtol=0.01)  # 10-bit steps


def test_the_right_ir_has_its_own_noise_and_the_mask_is_the_lit_wall_both_see():
    spec = stereo_spec()
    frame = make_frame(wall_passes(spec), spec, noise(0, 1))
    again = make_frame(wall_passes(spec), spec, noise(0, 2))
    np.testing.assert_array_equal(again["ir"], frame["ir"])  # the left stream is the left's alone
    assert not np.array_equal(again["ir_right"], frame["ir_right"])
    assert not np.array_equal(frame["ir_right"], frame["ir"])
    camera = spec.rig.camera
    disparity = camera.fx * spec.rig.second_camera_translation[0] / 2.0  # 2.1 px at the wall
    leaving = np.arange(camera.width) - disparity < -0.5  # the right camera's view ends there
    expected = np.ones((camera.height, camera.width), bool)
    expected[:, leaving] = False
    expected[:, 30:33] = False  # the projector's shadow
    np.testing.assert_array_equal(frame["stereo_visibility"], expected)


def test_a_stereo_frame_needs_the_right_passes_and_noise_stream():
    spec = stereo_spec()
    passes = wall_passes(spec)
    with pytest.raises(ValueError, match=r"^scene 0 frame 2: 1 SensorStreams for the spec's 2 camera\(s\); "
                                         r"each camera draws from streams of its own$"):
        make_frame(passes, spec, noise(0), where="scene 0 frame 2")
    del passes["depth_right"]
    with pytest.raises(ValueError, match=r"raw passes lack \['depth_right'\]"):
        make_frame(passes, spec, noise(0, 1))
    mono = replace(spec, cameras=spec.cameras[:1])
    assert set(make_frame(passes, mono, noise(0))) == set(stored_channels(
        rendered_channels(stereo=False)))


def test_each_camera_of_a_stereo_pair_sees_a_speckle_field_of_its_own():
    """Same direct light on both imagers: the speckle factors of the left and right IR are uncorrelated
    (two apertures centimetres apart), and each stays put for its pose."""
    spec = stereo_spec(exposure="fixed", gain=1.0, bloom_strength=0.0, blur_sigma=0.0, read_noise=0.0,
                       shot_noise=0.0, bit_depth=16, speckle_contrast=0.5, speckle_grain=40.0)
    passes = wall_passes(spec)
    frame = make_frame(passes, spec, frame_streams(0, spec, 0))
    again = make_frame(passes, spec, frame_streams(1, spec, 0))  # other noise streams, the same speckle
    np.testing.assert_array_equal(frame["ir_right"], again["ir_right"])
    lit = passes["flood"] > 0
    left = (frame["ir"][lit] - passes["ambient"][lit]) / passes["projector"][lit]  # the speckle factors
    right = (frame["ir_right"][lit] - passes["ambient_right"][lit]) / passes["projector_right"][lit]
    assert left.std() > 0.2 and right.std() > 0.2
    assert abs(np.corrcoef(left, right)[0, 1]) < 0.2


def test_radiance_beyond_float16_saturates_and_the_frame_can_be_written():
    """A rendered scene failed its write on one flood pixel of 164585 (a lamp or a surface against the
    projector): the stored ambient and flood saturate at float16's largest value there and keep every
    other pixel as they were."""
    spec = spec_with()
    passes = raw_frame(ambient=0.5, direct=0.2)
    frame = make_frame(passes, spec, frame_streams(0, spec, 0))
    passes["flood"][3, 4] = 164585.0
    passes["ambient"][5, 6] = 1e6
    hot = make_frame(passes, spec, frame_streams(0, spec, 0))
    assert hot["flood"][3, 4] == hot["ambient"][5, 6] == 65504.0 == float(np.finfo(np.float16).max)
    for name in ("flood", "ambient"):
        others = np.ones(SHAPE, bool)
        others[3, 4] = others[5, 6] = False
        np.testing.assert_array_equal(hot[name][others], frame[name][others])
    encode_frame(hot, SHAPE, stored_channels(rendered_channels(stereo=False)))  # no FormatError


def dotted_wall_passes(spec, distance: float) -> dict[str, np.ndarray]:
    """Raw passes of both cameras of a wall `distance` m away lit by a dot texture: the right camera's
    dots fx B / distance px to the left of the left camera's (a rectified pair), drawn as Gaussians."""
    camera = spec.rig.camera
    shift = camera.fx * spec.rig.second_camera_translation[0] / distance
    rng = np.random.default_rng(5)
    n = camera.width * camera.height // 12
    x, y = rng.uniform(-40, camera.width + 40, n), rng.uniform(-3, camera.height + 3, n)
    u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))

    def dots(offset: float) -> np.ndarray:
        image = np.zeros(u.shape, np.float32)
        for cx, cy in zip(x + offset, y, strict=True):
            near = (np.abs(u - cx) < 4) & (np.abs(v - cy) < 4)
            image[near] += np.exp(-((u[near] - cx) ** 2 + (v[near] - cy) ** 2) / 1.6).astype(np.float32)
        return image

    shape = u.shape
    flat = np.ones(shape, np.float32)
    passes = {}
    for suffix, projector in (("", dots(shift)), ("_right", dots(0.0))):
        passes |= {f"projector{suffix}": projector, f"flood{suffix}": flat,
                   f"ambient{suffix}": np.full(shape, 0.02, np.float32),
                   f"depth{suffix}": np.full(shape, distance, np.float32),
                   f"projector_direct{suffix}": projector, f"flood_direct{suffix}": flat}
    return passes


def test_a_stereo_frame_with_the_device_engine_on_carries_the_devices_depth():
    """realsense_d415 at scale 0.25 (320 x 180, fx 251 px, B 55 mm), a dotted wall at 1.2 m (11.5 px),
    noise off: device_depth is declared and stored, NaN over the left band (128 x 0.25 = 32
    disparities: columns 0-30), and elsewhere the wall's depth, all but a few pixels within a
    disparity step (the depth unit adds at most 0.005 px here)."""
    config = config_from_dict({"rig": {"preset": "realsense_d415", "scale": 0.25, "stereo": True},
                               "sensor": {"shot_noise": 0.0, "read_noise": 0.0, "bloom_strength": 0.0},
                               "device_depth": {"engine": "stereo", "subpixel_step": 0.125}})
    spec = sample_scene_spec(config, 0, 0, "train", SceneResources("/p.png", "0" * 64))
    assert frame_channels(spec) == rendered_channels(True, ("device_depth",))
    frame = make_frame(dotted_wall_passes(spec, 1.2), spec, frame_streams(0, spec, 0))
    assert tuple(frame) == stored_channels(rendered_channels(True, ("device_depth",)))
    depth = frame["device_depth"]
    assert depth.dtype == np.float32 and np.isnan(depth[:, :31]).all()
    inside = depth[10:-10, 40:-10]
    assert np.isfinite(inside).mean() > 0.8
    fx_b = spec.rig.camera.fx * 0.055
    error = np.abs(fx_b / inside[np.isfinite(inside)] - fx_b / 1.2)
    # the sensor model's blur and 10-bit levels: 4 of 43200 pixels were 0.133 px off (a step + 0.008)
    assert np.median(error) < 0.07 and (error <= 0.125 + 0.005).mean() > 0.999 and error.max() < 0.2
    # the codec takes it: no FormatError
    encode_frame(frame, depth.shape, stored_channels(rendered_channels(True, ("device_depth",))))


def test_the_stereo_engine_needs_the_stereo_pair():
    with pytest.raises(Exception, match=r"\[device_depth\] engine = \"stereo\" matches the left IR "
                       r"against the right one, which \[rig\] stereo = false does not render"):
        config_from_dict({"rig": {"preset": "realsense_d415"}, "device_depth": {"engine": "stereo"}})


def test_the_ambient_is_scaled_to_the_target_ratio_where_the_projector_reaches():
    """[lighting] ambient_ratio r: the ambient passes times one factor, so that the ambient light over
    the projector's light, both averaged where the projector reaches directly, is r."""
    raw = raw_frame(0.03, 0.1, 0.02)  # ambient 0.03, the projector 0.12, on the left half only
    half = SHAPE[1] // 2
    for name in ("projector", "projector_direct", "flood_direct"):
        raw[name][:, half:] = 0.0
    spec = spec_with()  # no noise, fixed exposure: ir = ambient + projector
    frame = make_frame(raw, replace(spec, ambient_ratio=5.0), noise(0))
    np.testing.assert_allclose(frame["ambient"], 5.0 * 0.12, rtol=1e-3)  # everywhere: one room
    np.testing.assert_allclose(frame["ir"][:, :half], 0.6 + 0.12, rtol=1e-3)
    np.testing.assert_allclose(frame["ir"][:, half:], 0.6, rtol=1e-3)
    as_rendered = make_frame(raw, spec, noise(0))
    np.testing.assert_allclose(as_rendered["ambient"], 0.03, rtol=1e-3)


def test_the_device_engine_sees_the_relit_ir():
    """The device's depth is made from the IR after the ambient is scaled to [lighting] ambient_ratio: the
    dotted wall of the test above (depth over 80% of its inside) drowned in 1e5 times the projector's
    light, where the dots are below a 10-bit level, gives depth almost nowhere."""
    config = config_from_dict({"rig": {"preset": "realsense_d415", "scale": 0.25, "stereo": True},
                               "sensor": {"shot_noise": 0.0, "read_noise": 0.0, "bloom_strength": 0.0},
                               "device_depth": {"engine": "stereo", "subpixel_step": 0.125}})
    spec = sample_scene_spec(config, 0, 0, "train", SceneResources("/p.png", "0" * 64))
    lit = replace(spec, ambient_ratio=1e5)
    depth = make_frame(dotted_wall_passes(spec, 1.2), lit, frame_streams(0, spec, 0))["device_depth"]
    assert np.isfinite(depth[10:-10, 40:-10]).mean() < 0.05
