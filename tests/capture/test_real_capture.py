"""`dotsim capture fit-sensor` on a real recording: the Kinect v1 IR frame vendored under
tests/data/real/kinect_v1_ctd (its README: source, licence). One 8-bit frame whose dots clip at 168-170
of 255 (4.7% of its pixels), the case a user of a public dataset meets.

The frame's true noise is not known; the ranges below are those a Kinect v1 frame can plausibly show
(a few grey levels of noise at most, dots 1-2 px wide at this resolution), wide enough to hold the
fit's standard error, and the clipped count is checked against numpy's own count of the frame.
"""

import tomllib
from pathlib import Path

import cv2
import numpy as np

from commands.cli import main

REAL = Path(__file__).resolve().parents[1] / "data" / "real" / "kinect_v1_ctd"
# Where the Kinect frame's clip starts (raw 8-bit value): values 168, 169 and 170 each hold more than
# ten times as many pixels as any value from 150 to 167 (counted by hand from its histogram).
CLIP = 168


def test_fit_sensor_on_a_real_kinect_frame(tmp_path, capsys):
    frame = cv2.imread(str(REAL / "ir.png"), cv2.IMREAD_UNCHANGED)
    assert frame.shape == (512, 640) and frame.dtype == np.uint8
    counts = np.bincount(frame.ravel(), minlength=256)
    assert counts[CLIP:171].min() > 10 * counts[150:CLIP].max()  # the clip's three codes, as stated
    clipped = int(counts[CLIP:].sum())

    output = tmp_path / "kinect.toml"
    status = main(["capture", "fit-sensor", str(REAL / "ir.png"), "-o", str(output)])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    out = captured.out
    assert f"saturation (clipped, left out)  {CLIP / 255:.4g}: {clipped} samples, " \
           f"{100 * clipped / frame.size:.2f}% of the projector-on samples" in out
    assert "note: one frame per scene: noise from flat regions of single frames" in out
    table = tomllib.loads(output.read_text())["sensor"]
    assert table["bit_depth"] == 8
    # noise: read noise below 1 grey level, shot noise such that the noise at half the clip level is
    # 1-3 grey levels of 255
    assert 0.0 < table["read_noise"] < 1 / 255
    assert 0.007 < table["shot_noise"] < 0.016
    half = 0.5 * CLIP / 255
    assert 1 / 255 < np.sqrt(table["read_noise"] ** 2 + table["shot_noise"] ** 2 * half) < 3 / 255
    fwhm = float(out.split("dot FWHM, px")[1].split()[0])
    isolated = int(out.split("dot FWHM, px")[1].split("(")[1].split()[0])
    assert 1.1 < fwhm < 2.0 and isolated >= 200
    snr = float(out.split("dot peak SNR, one frame")[1].split()[1].rstrip(","))
    assert 15 < snr < 60


def test_matched_depths_of_the_real_frame_lie_where_its_room_is():
    """capture.realism.matched_depths (its doctest: a pattern shifted by a known disparity comes back at
    fx b / d) on the real frame against its pattern: most of the frame is the wall 2.4-3 m away (its
    disparity 29-36 px at fx 1160, b 7.5 cm), nothing in it nearer than the Kinect's 0.4 m."""
    import doctest

    from capture import realism

    assert doctest.testmod(realism).failed == 0
    frame, pattern = (cv2.imread(str(REAL / name), cv2.IMREAD_UNCHANGED) / 255.0
                      for name in ("ir.png", "pattern.png"))
    depths = realism.matched_depths(frame, pattern, 1160.0, 0.075, 176)
    assert depths.size > 0.8 * 512 * (640 - 176)
    low, median, high = np.percentile(depths, [5, 50, 95])
    assert 1.5 < low < median < high < 3.5 and 2.4 < median < 3.0, (low, median, high)
    assert depths.min() > 0.4
