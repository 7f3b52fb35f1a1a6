"""capture.photon_transfer against frames of known noise: the generator's own sensor model
(dotsim.sensor.model.SensorModel.apply) makes them, the photon transfer measures them back."""

import doctest

import numpy as np
import pytest

from capture import photon_transfer
from capture.frames import CaptureError
from capture.photon_transfer import (
    MIN_BIN_BLOCKS,
    Estimate,
    Levels,
    NoiseBins,
    bit_depth,
    check_static,
    noise_curve,
    spatial_noise_bins,
    temporal_noise_bins,
)
from dotsim.sensor.model import SensorModel
from dotsim.sensor.settings import SensorSpec

READ, SHOT = 0.004, 0.02


def sensor(bits: int = 10) -> SensorModel:
    return SensorModel(SensorSpec(exposure="fixed", gain=1.0, bloom_strength=0.0, blur_sigma=0.0,
                                      read_noise=READ, shot_noise=SHOT, bit_depth=bits))


def ramp_scene(height: int = 120, width: int = 160) -> np.ndarray:
    """A still scene whose light goes from dark to bright across the image."""
    return np.tile(np.linspace(0.01, 0.9, width), (height, 1))


def test_docstring_examples():
    result = doctest.testmod(photon_transfer)
    assert result.attempted > 0 and result.failed == 0


@pytest.mark.parametrize("bits", [10, 16])
def test_photon_transfer_over_time_recovers_read_and_shot_noise(bits):
    model, rng = sensor(bits), np.random.default_rng(0)
    frames = np.stack([model.apply(ramp_scene(), rng) for _ in range(16)]).astype(np.float64)
    bins = NoiseBins()
    temporal_noise_bins(frames, 1.0, bins)
    curve = noise_curve(bins, 1 / (2**bits - 1), "temporal")
    read, shot = curve.read_noise(), curve.shot_noise()
    assert read.value == pytest.approx(READ, rel=0.05) and shot.value == pytest.approx(SHOT, rel=0.03)
    # the errors are honest: the truth within 4 of them, and them small
    assert abs(read.value - READ) < 4 * read.error < 0.05 * READ
    assert abs(shot.value - SHOT) < 4 * shot.error < 0.05 * SHOT


def test_flat_regions_of_one_frame_give_the_noise_and_pass_over_structure():
    """Planar patches of one frame (slopes, levels), with dots and edges in between: the blocks that
    scatter more than the noise (dots, edges) are dropped."""
    rng = np.random.default_rng(1)
    y, x = np.mgrid[0:240, 0:320]
    scene = 0.05 + 0.8 * (x // 40) / 8 + 0.0005 * y  # steps every 40 px: edges; a slope down
    scene[::16, ::16] += 0.3  # a dot in some blocks
    frame = sensor(16).apply(np.clip(scene, 0, 0.95), rng).astype(np.float64)
    bins = NoiseBins(min_count=MIN_BIN_BLOCKS)
    spatial_noise_bins(frame, 1.0, bins)
    curve = noise_curve(bins, 1 / 65535, "spatial")
    assert curve.read_noise().value == pytest.approx(READ, rel=0.1)
    assert curve.shot_noise().value == pytest.approx(SHOT, rel=0.05)


def test_too_few_levels_is_one_line():
    bins = NoiseBins()
    temporal_noise_bins(np.full((4, 10, 10), 0.5) + np.random.default_rng(0).normal(0, 0.01, (4, 10, 10)),
                        1.0, bins)
    with pytest.raises(CaptureError, match=r"^too few levels to fit the noise: 1 level bin\(s\) of at least "
                       r"50 unclipped pixels; allowed: 3 or more"):
        noise_curve(bins, 0.0, "temporal")


def test_bit_depth_saturation_and_black_level():
    scene = ramp_scene() * 1.3
    scene[:, :10] = 0.013  # a dark strip: the darkest light
    frames = np.stack([sensor(10).apply(scene, np.random.default_rng(k)) for k in range(4)])
    assert bit_depth(frames.astype(np.float16).astype(np.float64), 2.0**-11) == 10  # as a dataset stores it
    assert bit_depth(frames.astype(np.float64), 2.0**-24) == 10  # float32, as the model gives it
    assert bit_depth(np.round(frames.astype(np.float64) * 1023) / 1023, 1e-9) == 10  # raw / white level
    assert bit_depth(np.round(frames.astype(np.float64) * 255) / 255, 1e-9) == 8
    levels = Levels()
    levels.add(frames.astype(np.float64), frames.mean(axis=0))
    assert levels.saturation() == 1.0 and levels.saturated_share == pytest.approx(np.mean(frames == 1.0))
    # the noise reaches 0 in the dark strip often enough: the sensor clips at 0, its black level
    assert np.mean(frames == 0) > 1e-4 and levels.black_level() == Estimate(0.0, 0.0)
    offset = Levels()  # a sensor with a black offset of 0.05 never reaches 0
    offset.add(frames.astype(np.float64) + 0.05, frames.mean(axis=0) + 0.05)
    black = offset.black_level()
    assert abs(black.value - 0.063) < max(4 * black.error, 0.0015)


def test_a_moving_scene_is_refused_and_a_still_one_passes():
    model, rng = sensor(10), np.random.default_rng(2)
    y, x = np.mgrid[0:100, 0:100]
    dots = lambda shift: 0.05 + 0.6 * (np.sin((x + shift) / 2) > 0.9)  # noqa: E731
    still = np.stack([model.apply(dots(0), rng) for _ in range(8)]).astype(np.float64)
    assert check_static(still, 1 / 1023, "still") < 0.001
    moved = np.stack([model.apply(dots(k // 4), rng) for k in range(8)]).astype(np.float64)  # 1 px after 4
    with pytest.raises(CaptureError, match=r"^scene 3: moving scene: \d+\.\d% of the pixels changed by more "
                       r"than 6 noise sigmas between the first and the second half of the frames \(allowed: "
                       r"0\.5%\); keep the sensor and the scene still while recording$"):
        check_static(moved, 1 / 1023, "scene 3")
