"""trainer/flat_regions.py: the plane-fit score against planes of known pose and noise, computed
independently here (the true plane, not the fitted one), and the hand-drawn regions of the vendored
capture."""

import json
from pathlib import Path

import numpy as np
import pytest

from dotsim.oracle_dataset import planar_depth
from dotsim.rig.geometry import depth_to_disparity
from dotsim.rig.presets import get_preset
from trainer.flat_regions import RegionsError, fit_plane, read_regions, region_residuals, score_regions

REAL = Path(__file__).resolve().parents[1] / "data" / "real" / "kinect_v1_ctd"


def test_a_tilted_wall_is_a_plane_in_disparity_space():
    """The premise: the exact disparity of a tilted plane (depth from the rig's geometry) is affine in
    the pixel coordinates, so its residual about the fitted plane is nil (float32 rounding)."""
    rig = get_preset("kinect_v1").scaled(0.5)
    disparity = depth_to_disparity(planar_depth(rig, 1.0, 0.4, -0.3), rig).astype(np.float64)
    labels = np.ones(disparity.shape, np.int32)
    row = score_regions(disparity, labels, ["wall"], plausible=(0.0, 1e3))[0]
    assert disparity.max() - disparity.min() > 10  # tilted: the disparity spans many pixels
    assert row["rms"] < 1e-4 and row["within"] == 1.0 and row["no value"] == 0.0


def test_noise_and_outliers_are_measured_about_the_true_plane():
    """Gaussian noise of known sigma plus 25 % gross outliers: the fit finds the true plane (not one pulled
    by the outliers), the RMS equals the RMS about the true plane computed here, and without outliers it
    is sigma."""
    rng = np.random.default_rng(3)
    v, u = np.mgrid[0:120, 0:160].astype(np.float64)
    true = 0.04 * u - 0.03 * v + 35.0
    sigma = 0.3
    noisy = true + rng.normal(0, sigma, true.shape)
    outliers = rng.random(true.shape) < 0.25
    spoiled = np.where(outliers, rng.uniform(10, 150, true.shape), noisy)
    fit = fit_plane(u.ravel(), v.ravel(), spoiled.ravel(), threshold=1.0)
    assert np.allclose(fit.coefficients, [0.04, -0.03, 35.0], atol=[2e-4, 2e-4, 0.03])
    labels = np.ones(true.shape, np.int32)
    row = score_regions(spoiled, labels, ["wall"], plausible=(5.0, 200.0))[0]
    independent = np.sqrt(np.mean((spoiled - true) ** 2))
    assert row["rms"] == pytest.approx(independent, rel=0.01)
    assert row["within"] == pytest.approx(np.mean(np.abs(spoiled - true) <= 1.0), abs=0.005)
    close = np.abs(spoiled - true) <= 1.0
    assert row["rms within"] == pytest.approx(np.sqrt(np.mean((spoiled - true)[close] ** 2)), rel=0.02)
    clean = score_regions(noisy, labels, ["wall"], plausible=(5.0, 200.0))[0]
    assert clean["rms"] == pytest.approx(sigma, rel=0.03)


def test_implausible_values_are_no_value_and_left_out_of_the_fit():
    """nan and values outside the plausible range count as no value, per region, and do not move the
    plane; two regions get planes of their own and "all" pools their residuals."""
    v, u = np.mgrid[0:50, 0:80].astype(np.float64)
    disparity = np.where(u < 40, 20.0 + 0.1 * v, 60.0 - 0.2 * u)
    disparity[0:10, 0:10] = np.nan  # 100 px of region 1
    disparity[40:50, 70:80] = 500.0  # 100 px of region 2, beyond the range
    labels = np.where(u < 40, 1, 2).astype(np.int32)
    rows = score_regions(disparity, labels, ["left", "right"], plausible=(10.0, 100.0))
    assert [r["region"] for r in rows] == ["left", "right", "all"]
    assert [r["no value"] for r in rows[:2]] == pytest.approx([100 / 2000, 100 / 2000])
    assert rows[2]["no value"] == pytest.approx(200 / 4000) and rows[2]["pixels"] == 4000
    assert np.allclose(rows[0]["plane"], [0.0, 0.1, 20.0])
    assert np.allclose(rows[1]["plane"], [-0.2, 0.0, 60.0])
    assert max(r["rms"] for r in rows) < 1e-9
    residuals, _ = region_residuals(disparity, labels, 2, (10.0, 100.0))
    assert np.isnan(residuals[0:10, 0:10]).all() and np.isfinite(residuals[20:, 10:70]).all()
    empty = score_regions(np.full((4, 4), np.nan), np.ones((4, 4), np.int32), ["none"], (1.0, 2.0))[0]
    assert empty["no value"] == 1.0 and np.isnan(empty["rms"]) and empty["plane"] is None


def test_the_vendored_regions_read_and_scale():
    """The capture's hand-drawn regions at half size: every pixel centre inside its scaled polygon
    (x' = (x + 0.5) / 2 - 0.5; OpenCV's point-in-polygon distance, not the fill the module draws with)
    carries its label, none more than a pixel outside does (the fill takes the border pixels too)."""
    import cv2

    half, names = read_regions(REAL / "flat_regions.json", (256, 320))
    assert names == ["upper wall", "lower wall", "fireplace surround", "right pillar"]
    polygons = [r["polygon"] for r in json.loads((REAL / "flat_regions.json").read_text())["regions"]]
    v, u = np.mgrid[0:256, 0:320]
    for k, polygon in enumerate(polygons, start=1):
        scaled = ((np.asarray(polygon, np.float64) + 0.5) * 0.5 - 0.5).astype(np.float32)
        distance = np.array([cv2.pointPolygonTest(scaled, (float(x), float(y)), True)
                             for x, y in zip(u.ravel(), v.ravel(), strict=True)]).reshape(u.shape)
        assert (distance > 0).sum() > 1000
        assert (half[distance > 0] == k).all() and not (half[distance < -1] == k).any()


def test_bad_regions_files_are_named(tmp_path):
    bad = tmp_path / "regions.json"
    bad.write_text('{"image_size": [64, 48]}')
    with pytest.raises(RegionsError, match="regions.json: not a regions file"):
        read_regions(bad, (48, 64))
    bad.write_text('{"image_size": [64, 48], "regions": [{"name": "a", "polygon": [[0, 0], [1, 1]]}]}')
    with pytest.raises(RegionsError, match="'a': polygon must be 3 or more"):
        read_regions(bad, (48, 64))
    bad.write_text('{"image_size": [64, 48], "regions": []}')
    with pytest.raises(RegionsError, match="another aspect ratio"):
        read_regions(bad, (48, 48))
