"""make_frame's laser speckle: on the projector's direct light only, fixed for a pose, off by default.

Noise-free sensor (no read or shot noise, 16 bits, fixed gain 1, no blur or bloom), so the stored ir
is ambient + projector x speckle up to 16-bit rounding, and the speckle factor can be read back.
"""

from dataclasses import replace

import numpy as np
import pytest

from dotsim.rig import get_preset
from generator.config import config_from_dict
from generator.post_render import make_frame
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
