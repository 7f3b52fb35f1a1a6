"""StereoSGBM's range and preprocessing: a plane at the nearest configured depth is recovered.

The test images are made independently of dotsim's renderer and oracle: random dots on the
reference grid, and the IR image that same texture shifted right by the disparity d = fx b / z of a
fronto-parallel plane (nearer surfaces move dots right, docs/GEOMETRY.md), resampled by OpenCV.
"""

import math

import cv2
import numpy as np
import pytest

from dotsim.config_schema import read_toml
from dotsim.configs import builtin_path
from dotsim.rig import get_preset
from generator.config import config_from_dict
from generator.sample_scene import build_rig
from trainer.sgbm import PREPROCESSINGS, max_disparity, num_disparities_for, sgbm_disparity


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
