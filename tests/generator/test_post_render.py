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
from dotsim.rig import get_preset
from generator.blender.frame_recipe import RAW_PASSES
from generator.config import config_from_dict
from generator.post_render import frame_channels, make_frame, raw_pass_names
from generator.sample_scene import SceneResources, sample_scene_spec

RIG = get_preset("structure_core").scaled(0.1)
SHAPE = (RIG.camera.height, RIG.camera.width)


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
    frames = [make_frame(raw_frame(0.03, 0.1, 0.02), spec, np.random.default_rng(k), frame=k)
              for k in range(4)]
    factors = [(frame["ir"].astype(np.float64) - 0.05) / 0.1 for frame in frames]
    for factor in factors:
        # 16-bit rounding of ir / 0.1: at most 8e-5 off a factor of mean 1 and std 0.5
        assert factor.mean() == pytest.approx(1.0, abs=0.06) and factor.std() == pytest.approx(0.5, rel=0.15)
        assert factor.min() >= 0.5 - 1e-4
    np.testing.assert_array_equal(frames[0]["ir"], frames[1]["ir"])  # one pose: the same speckle
    assert np.corrcoef(factors[0].ravel(), factors[2].ravel())[0, 1] < 0.2  # another pose: another
    assert np.corrcoef(factors[2].ravel(), factors[3].ravel())[0, 1] < 0.2
    # without direct light nothing is speckled, and speckle off is the plain sum
    dark = make_frame(raw_frame(0.3, 0.0, 0.1), spec, np.random.default_rng(0), frame=0)
    np.testing.assert_allclose(dark["ir"], 0.4, atol=1e-5)
    plain = make_frame(raw_frame(0.2, 0.5), spec_with(), np.random.default_rng(0))
    np.testing.assert_allclose(plain["ir"], 0.7, atol=1e-5)


def test_speckle_needs_the_frame_index():
    spec = spec_with(speckle_contrast=0.5)
    with pytest.raises(ValueError, match=r"scene 0 frame 7: frame = None: the sensor's speckle needs the "
                       r"frame's index in the spec's poses, 0 to 3"):
        make_frame(raw_frame(0.2, 0.5), spec, np.random.default_rng(0), where="scene 0 frame 7")
    with pytest.raises(ValueError, match="frame = 4"):
        make_frame(raw_frame(0.2, 0.5), spec, np.random.default_rng(0), frame=4)


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
    rng = np.random.default_rng
    frame = make_frame(wall_passes(spec), spec, rng(0), right_rng=rng(1))
    assert tuple(frame) == stored_channels(rendered_channels(stereo=True))
    np.testing.assert_array_equal(frame["ir_right"], frame["ir"])
    passes = wall_passes(spec, right_gain=2.0)
    brighter = make_frame(passes, spec, rng(0), right_rng=rng(1))
    np.testing.assert_array_equal(brighter["ir"], frame["ir"])
    left_light = passes["ambient"] + passes["projector"]
    right_light = passes["ambient_right"] + passes["projector_right"]
    unclipped = (brighter["ir_right"] < 1) & (left_light > 0.3)
    gain_left = frame["ir"][unclipped] / left_light[unclipped]
    gain_right = brighter["ir_right"][unclipped] / right_light[unclipped]
    np.testing.assert_allclose(gain_right, gain_left, rtol=0.01)  # 10-bit steps


def test_the_right_ir_has_its_own_noise_and_the_mask_is_the_lit_wall_both_see():
    spec = stereo_spec()
    rng = np.random.default_rng
    frame = make_frame(wall_passes(spec), spec, rng(0), right_rng=rng(1))
    again = make_frame(wall_passes(spec), spec, rng(0), right_rng=rng(2))
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
    with pytest.raises(ValueError, match="scene 0 frame 2: the spec renders the stereo pair; the right "
                                         r"camera needs a noise stream of its own \(right_rng\)"):
        make_frame(passes, spec, np.random.default_rng(0), where="scene 0 frame 2")
    del passes["depth_right"]
    with pytest.raises(ValueError, match=r"raw passes lack \['depth_right'\]"):
        make_frame(passes, spec, np.random.default_rng(0), right_rng=np.random.default_rng(1))
    mono = replace(spec, cameras=spec.cameras[:1])
    assert set(make_frame(passes, mono, np.random.default_rng(0))) == set(stored_channels(
        rendered_channels(stereo=False)))


def test_each_camera_of_a_stereo_pair_sees_a_speckle_field_of_its_own():
    """Same direct light on both imagers: the speckle factors of the left and right IR are uncorrelated
    (two apertures centimetres apart), and each stays put for its pose."""
    spec = stereo_spec(exposure="fixed", gain=1.0, bloom_strength=0.0, blur_sigma=0.0, read_noise=0.0,
                       shot_noise=0.0, bit_depth=16, speckle_contrast=0.5, speckle_grain=40.0)
    passes = wall_passes(spec)
    rng = np.random.default_rng
    frame = make_frame(passes, spec, rng(0), right_rng=rng(1), frame=0)
    again = make_frame(passes, spec, rng(2), right_rng=rng(3), frame=0)
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
    frame = make_frame(passes, spec, np.random.default_rng(0), frame=0)
    passes["flood"][3, 4] = 164585.0
    passes["ambient"][5, 6] = 1e6
    hot = make_frame(passes, spec, np.random.default_rng(0), frame=0)
    assert hot["flood"][3, 4] == hot["ambient"][5, 6] == 65504.0 == float(np.finfo(np.float16).max)
    for name in ("flood", "ambient"):
        others = np.ones(SHAPE, bool)
        others[3, 4] = others[5, 6] = False
        np.testing.assert_array_equal(hot[name][others], frame[name][others])
    encode_frame(hot, SHAPE, stored_channels(rendered_channels(stereo=False)))  # no FormatError


def test_the_ambient_is_scaled_to_the_target_ratio_where_the_projector_reaches():
    """[lighting] ambient_ratio r: the ambient passes times one factor, so that the ambient light over
    the projector's light, both averaged where the projector reaches directly, is r."""
    raw = raw_frame(0.03, 0.1, 0.02)  # ambient 0.03, the projector 0.12, on the left half only
    half = SHAPE[1] // 2
    for name in ("projector", "projector_direct", "flood_direct"):
        raw[name][:, half:] = 0.0
    spec = spec_with()  # no noise, fixed exposure: ir = ambient + projector
    frame = make_frame(raw, replace(spec, ambient_ratio=5.0), np.random.default_rng(0))
    np.testing.assert_allclose(frame["ambient"], 5.0 * 0.12, rtol=1e-3)  # everywhere: one room
    np.testing.assert_allclose(frame["ir"][:, :half], 0.6 + 0.12, rtol=1e-3)
    np.testing.assert_allclose(frame["ir"][:, half:], 0.6, rtol=1e-3)
    as_rendered = make_frame(raw, spec, np.random.default_rng(0))
    np.testing.assert_allclose(as_rendered["ambient"], 0.03, rtol=1e-3)
