"""StereoSGBM's range and preprocessing: a plane at the nearest configured depth is recovered.

The test images are made independently of dotsim's renderer and oracle: random dots on the
reference grid, and the IR image that same texture shifted right by the disparity d = fx b / z of a
fronto-parallel plane (nearer surfaces move dots right, docs/GEOMETRY.md), resampled by OpenCV.
"""

import doctest
import math

import cv2
import numpy as np
import pytest

from dotsim.config_schema import read_toml
from dotsim.configs import builtin_path
from dotsim.rig.presets import get_preset
from generator.config import config_from_dict
from generator.sample_scene import build_rig
from trainer import sgbm
from trainer.sgbm import (
    PREPROCESSINGS,
    max_disparity,
    num_disparities_for,
    published_num_disparities,
    sgbm_disparity,
    stereo_sgbm_disparity,
)


def shifted_pair(height: int, width: int, disparity: float, seed: int = 0):
    """(ir, reference): Gaussian dots on the reference, the IR the reference moved right by `disparity`
    px, with a little noise, and the IR's brightness falling off to the right (as dots dim with depth)."""
    rng = np.random.default_rng(seed)
    reference = np.zeros((height, width), np.float32)
    ys, xs = rng.integers(0, height, width * height // 40), rng.integers(0, width, width * height // 40)
    reference[ys, xs] = 1.0
    reference = cv2.GaussianBlur(reference, (0, 0), 0.8)
    reference /= reference.max()
    shift = np.float32([[1, 0, disparity], [0, 1, 0]])
    ir = cv2.warpAffine(reference, shift, (width, height), flags=cv2.INTER_CUBIC)
    ir = ir * np.linspace(1.0, 0.4, width, dtype=np.float32)[None] + rng.normal(0, 0.01, ir.shape)
    return np.clip(ir, 0, 1).astype(np.float32), reference


def structure_core_half():
    """The shipped structure_core config (its rig and scene distance; primitives, so no asset cache
    is needed) and its rig at half size."""
    data = read_toml(builtin_path("structure_core"))
    data["assets"] = {"source": "primitives"}
    config = config_from_dict(data, "structure_core")
    return config, build_rig(config).scaled(0.5)


def test_num_disparities_reach_the_nearest_depth():
    rig = get_preset("structure_core").scaled(0.5)  # 608 x 448: fx 557.7 px, b 0.0634 m
    assert max_disparity(rig, 0.3) == pytest.approx(rig.camera.fx * rig.baseline / 0.3)
    n = num_disparities_for(rig, 0.3)
    assert n % 16 == 0 and n - 16 < max_disparity(rig, 0.3) + 2 <= n  # the smallest that holds it
    assert n == 128  # d = 117.9 px at 0.3 m; the published 128 scaled to 608 px (64) would stop at 0.55 m
    assert num_disparities_for(rig, 20.0) == 16
    with pytest.raises(ValueError, match="nearest depth"):
        num_disparities_for(rig, 0.0)


@pytest.mark.parametrize("preprocessing", PREPROCESSINGS)
def test_sgbm_recovers_a_plane_at_the_nearest_configured_depth(preprocessing):
    config, rig = structure_core_half()
    nearest = config.scene.distance[0]
    d = rig.camera.fx * rig.baseline / nearest  # about 118 px at 0.3 m
    height, width = 120, 400
    ir, reference = shifted_pair(height, width, d)
    disparity = sgbm_disparity(ir, reference, num_disparities_for(rig, nearest), preprocessing=preprocessing)
    inner = disparity[8:-8, math.ceil(d) + 8 : -8]  # where the shifted texture exists
    assert np.isfinite(inner).mean() > 0.95
    assert np.mean(np.abs(inner - d) <= 0.5) > 0.9, (np.nanmedian(inner), d)
    # the published range scaled with the width never reaches this plane
    assert d > 64
    short = sgbm_disparity(ir, reference, 64, preprocessing=preprocessing)[8:-8, math.ceil(d) + 8 : -8]
    assert np.mean(np.abs(short - d) <= 0.5) < 0.05


def test_sgbm_rejects_a_bad_range_or_preprocessing():
    ir, reference = shifted_pair(32, 64, 4.0)
    with pytest.raises(ValueError, match="multiple of 16"):
        sgbm_disparity(ir, reference, 40)
    with pytest.raises(ValueError, match="preprocessing"):
        sgbm_disparity(ir, reference, 16, preprocessing="census")


def test_published_range_scales_128_disparities_with_the_width():
    result = doctest.testmod(sgbm)
    assert result.attempted > 0 and result.failed == 0
    assert published_num_disparities(100) == 16  # never less than SGBM's one block of 16


@pytest.mark.parametrize("range_from", ["data", "published"])
def test_stereo_sgbm_recovers_a_plane_from_the_left_and_right_ir(range_from):
    """A RealSense D435 pair at half size (640 px: fx 337.2 px, B 0.05 m) before a plane at 0.35 m:
    the left IR is the right IR moved right by d = fx B / z (the left pixel u sees what the right one
    sees at u - d), each with its own noise, the left a little brighter (one exposure, but not one
    scene radiance everywhere). SGBM between them gives d on nearly every pixel both see."""
    rig = get_preset("realsense_d435").scaled(0.5)
    baseline = rig.second_camera_translation[0]
    d = rig.camera.fx * baseline / 0.35  # 48.2 px
    right, _ = shifted_pair(120, 400, 0.0, seed=3)
    left, _ = shifted_pair(120, 400, d, seed=3)  # the same dots, moved right by d
    rng = np.random.default_rng(4)
    left = np.clip(1.05 * left + rng.normal(0, 0.01, left.shape), 0, 1).astype(np.float32)
    n = num_disparities_for(rig, 0.3, baseline) if range_from == "data" else published_num_disparities(640)
    assert n == {"data": 64, "published": 80}[range_from]
    disparity = stereo_sgbm_disparity(left, right, n)
    inner = disparity[8:-8, math.ceil(d) + 8 : -8]
    assert np.isfinite(inner).mean() > 0.95
    assert np.mean(np.abs(inner - d) <= 0.5) > 0.9, (np.nanmedian(inner), d)
    with pytest.raises(ValueError, match=r"left \(120, 400\) and right \(120, 399\) IR must have the same"):
        stereo_sgbm_disparity(left, right[:, 1:], n)
