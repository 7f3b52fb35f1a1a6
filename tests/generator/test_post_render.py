"""The post-render of a stereo pair's frame, on hand-made raw passes (no Blender): the right IR through
the same sensor model at the left frame's exposure with a noise stream of its own, and the stereo
mask of a wall both cameras see."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dotsim.channels import rendered_channels, stored_channels
from generator.blender.frame_recipe import RAW_PASSES
from generator.config import config_from_dict
from generator.post_render import frame_channels, make_frame, raw_pass_names
from generator.sample_scene import SceneResources, sample_scene_spec


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
