"""Dot patterns: generation, rendering, detection, statistics and loading, against hand-made images."""

import argparse
import json

import cv2
import numpy as np
import OpenEXR
import pytest
from scipy.spatial.distance import pdist

from commands import pattern as pattern_command
from dotsim.patterns import (
    DotPattern,
    PatternError,
    detect_dots,
    generate_dot_pattern,
    load_pattern,
    pattern_from_centres,
    pattern_statistics,
    render_dots,
    row_window_uniqueness,
)


def _grid_centres(nx=7, ny=5, spacing=11.0, origin=(8.3, 6.7)):
    x, y = np.meshgrid(origin[0] + spacing * np.arange(nx), origin[1] + spacing * np.arange(ny))
    return np.stack([x.ravel(), y.ravel()], axis=1)


def _write_exr(path, channels):
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    pixels = {name: np.ascontiguousarray(values, np.float32) for name, values in channels.items()}
    OpenEXR.File(header, pixels).write(str(path))


def test_same_seed_same_pattern_and_other_seed_differs():
    a = generate_dot_pattern(200, 150, n_dots=400, seed=3)
    b = generate_dot_pattern(200, 150, n_dots=400, seed=3)
    c = generate_dot_pattern(200, 150, n_dots=400, seed=4)
    assert a.sha256 == b.sha256 and np.array_equal(a.centres, b.centres)
    assert a.sha256 != c.sha256
    assert a.params["seed"] == 3 and a.params["generator"] == "poisson_disc"


@pytest.mark.parametrize("min_spacing", [2.0, 4.5])
def test_min_spacing_and_dot_count_are_respected(min_spacing):
    pattern = generate_dot_pattern(160, 120, density=0.02, min_spacing=min_spacing, seed=1)
    assert len(pattern.centres) == round(0.02 * 160 * 120)
    assert pdist(pattern.centres).min() >= min_spacing
    assert (pattern.centres >= -0.5).all() and (pattern.centres[:, 0] < 159.5).all()
    assert (pattern.centres[:, 1] < 119.5).all()


def test_too_many_dots_for_the_spacing_is_refused():
    with pytest.raises(PatternError, match="could only place .* lower n_dots/density"):
        generate_dot_pattern(50, 50, n_dots=1000, min_spacing=3.0)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"n_dots": 10, "density": 0.1}, "not both"),
        ({"density": -0.1}, "density must be a positive"),
        ({"n_dots": 0}, "n_dots must be a positive integer"),
        ({"n_dots": 10, "min_spacing": float("nan")}, "min_spacing"),
    ],
)
def test_bad_generation_parameters_are_named(kwargs, message):
    with pytest.raises(PatternError, match=message):
        generate_dot_pattern(40, 30, **kwargs)
    with pytest.raises(PatternError, match="width must be a positive integer"):
        generate_dot_pattern(0, 30)


def test_render_dots_draws_point_sampled_gaussians():
    sigma = 1.3
    image = render_dots(np.array([[20.25, 14.6]]), 40, 30, sigma)
    yy, xx = np.mgrid[:30, :40]
    expected = np.exp(-((xx - 20.25) ** 2 + (yy - 14.6) ** 2) / (2 * sigma**2))
    expected[(np.abs(xx - 20) > 6) | (np.abs(yy - 15) > 6)] = 0  # splat window +-ceil(4 sigma)
    np.testing.assert_allclose(image, expected, atol=1e-6)
    assert image.sum() == pytest.approx(2 * np.pi * sigma**2, rel=1e-3)


def test_pattern_from_centres_rejects_bad_centres():
    with pytest.raises(PatternError, match="index 1 = \\[50.0, 3.0\\]"):
        pattern_from_centres(np.array([[1.0, 1.0], [50.0, 3.0]]), 40, 30)
    with pytest.raises(PatternError, match="not finite"):
        pattern_from_centres(np.array([[np.nan, 1.0]]), 40, 30)
    with pytest.raises(PatternError, match="non-empty \\(N, 2\\)"):
        pattern_from_centres(np.zeros((0, 2)), 40, 30)
    with pytest.raises(PatternError, match="sigma"):
        pattern_from_centres(np.array([[1.0, 1.0]]), 40, 30, sigma=0.0)


def test_detect_dots_finds_hand_placed_dots_to_sub_pixel():
    centres = _grid_centres()
    pattern = pattern_from_centres(centres, 90, 60, sigma=1.0)
    found = detect_dots(pattern.image)
    assert len(found) == len(centres)
    order = np.lexsort((found[:, 0], found[:, 1]))
    np.testing.assert_allclose(found[order], centres[np.lexsort((centres[:, 0], centres[:, 1]))], atol=2e-3)


def test_detect_dots_counts_a_plateau_once():
    image = np.zeros((9, 9))
    image[4, 3:5] = 1.0
    image[1, 7] = 0.5
    assert len(detect_dots(image)) == 2
    assert len(detect_dots(np.zeros((5, 5)))) == 0


def test_statistics_of_a_hand_made_pattern():
    centres = _grid_centres(spacing=11.0)
    stats = pattern_statistics(pattern_from_centres(centres, 90, 60, sigma=1.0), window=9, search=40)
    assert stats["dot_count"] == 35
    assert stats["density"] == pytest.approx(35 / (90 * 60))
    assert stats["mean_spacing"] == pytest.approx(11.0, abs=0.01)
    assert stats["min_spacing"] == pytest.approx(11.0, abs=0.01)
    # a regular grid repeats every 11 px: no window is unique within a 40 px search
    assert stats["row_window_uniqueness"] == 0.0


def test_random_dense_pattern_rows_are_unique_and_empty_windows_are_not():
    dense = generate_dot_pattern(400, 120, density=0.04, seed=2)
    assert row_window_uniqueness(dense.image, window=9, search=64)["unique_share"] > 0.95
    # two identical dots 30 px apart: every window holding one has an exact copy 30 px away
    sparse = np.zeros((40, 200))
    sparse[20, 85] = sparse[20, 115] = 1.0
    result = row_window_uniqueness(sparse, window=9, search=64, n_rows=20)
    assert result["unique_share"] == 0.0 and result["flat_share"] > 0.9


def test_png_round_trip_is_exact_and_atomic(tmp_path):
    pattern = generate_dot_pattern(120, 80, n_dots=100, seed=0)
    path = pattern.save_png(tmp_path / "sub" / "pattern.png")
    assert sorted(p.name for p in path.parent.iterdir()) == ["pattern.png"]  # no temp file left over
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw.shape == (80, 120)
    loaded = load_pattern(path, expected_shape=(80, 120))
    assert loaded.sha256 == pattern.sha256
    assert np.array_equal(loaded.image, pattern.image)
    with pytest.raises(PatternError, match="written as .png"):
        pattern.save_png(tmp_path / "pattern.tif")


def test_load_8_bit_png_and_colour_png(tmp_path):
    grey = (np.arange(60 * 40) % 256).astype(np.uint8).reshape(40, 60)
    cv2.imwrite(str(tmp_path / "grey.png"), grey)
    np.testing.assert_allclose(load_pattern(tmp_path / "grey.png").image, grey / 255.0, atol=1e-7)
    colour = np.stack([grey, grey, grey], axis=2)
    cv2.imwrite(str(tmp_path / "colour.png"), colour)
    np.testing.assert_allclose(load_pattern(tmp_path / "colour.png").image, grey / 255.0, atol=1e-7)


def test_load_exr_channels_scaled_to_max_one(tmp_path):
    values = np.random.default_rng(0).random((30, 50)) * 7.0
    _write_exr(tmp_path / "y.exr", {"Y": values})
    loaded = load_pattern(tmp_path / "y.exr")
    np.testing.assert_allclose(loaded.image, values / values.max(), atol=2e-5)
    _write_exr(tmp_path / "rgb.exr", {"R": values, "G": values * 0, "B": values * 0})
    np.testing.assert_allclose(load_pattern(tmp_path / "rgb.exr").image, values / values.max(), atol=2e-5)
    _write_exr(tmp_path / "two.exr", {"A": values, "Z": values})
    with pytest.raises(PatternError, match="two.exr: EXR has channels \\['A', 'Z'\\]"):
        load_pattern(tmp_path / "two.exr")


def test_bad_pattern_files_are_named_with_the_problem(tmp_path):
    with pytest.raises(PatternError, match="missing.png: no such file"):
        load_pattern(tmp_path / "missing.png")
    (tmp_path / "empty.png").write_bytes(b"")
    with pytest.raises(PatternError, match="empty.png: file is empty"):
        load_pattern(tmp_path / "empty.png")
    (tmp_path / "text.png").write_text("not a picture")
    with pytest.raises(PatternError, match="text.png: not a readable PNG image"):
        load_pattern(tmp_path / "text.png")
    (tmp_path / "text.exr").write_text("not a picture")
    with pytest.raises(PatternError, match="text.exr: not a readable EXR"):
        load_pattern(tmp_path / "text.exr")
    cv2.imwrite(str(tmp_path / "flat.png"), np.full((20, 20), 7, np.uint8))
    with pytest.raises(PatternError, match="flat.png: image is constant"):
        load_pattern(tmp_path / "flat.png")
    cv2.imwrite(str(tmp_path / "small.png"), np.eye(20, dtype=np.uint8) * 255)
    with pytest.raises(PatternError, match="small.png: pattern is 20x20 .* expected 30x10"):
        load_pattern(tmp_path / "small.png", expected_shape=(10, 30))
    nan = np.eye(20)
    nan[3, 3] = np.nan
    _write_exr(tmp_path / "nan.exr", {"Y": nan})
    with pytest.raises(PatternError, match="nan.exr: image contains 1 NaN/inf"):
        load_pattern(tmp_path / "nan.exr")
    _write_exr(tmp_path / "negative.exr", {"Y": np.eye(20) - 0.5})
    with pytest.raises(PatternError, match="negative.exr: image has negative values"):
        load_pattern(tmp_path / "negative.exr")


def test_dot_pattern_refuses_nan_and_non_2d():
    with pytest.raises(PatternError, match="NaN"):
        DotPattern(np.array([[0.0, np.nan]]))
    with pytest.raises(PatternError, match="2-D"):
        DotPattern(np.zeros(5))


def _cli(argv):
    parser = argparse.ArgumentParser(prog="dotsim")
    pattern_command.add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


def test_cli_make_and_stats(tmp_path, capsys):
    out = tmp_path / "pattern.png"
    assert _cli(["pattern", "make", "--rig", "kinect_v1", "--scale", "0.25", "--seed", "5",
                 "--density", "0.03", "-o", str(out)]) == 0
    pattern = load_pattern(out)
    assert (pattern.width, pattern.height) == (400, 300)  # kinect_v1 projector 1600 x 1200 at 0.25
    expected = generate_dot_pattern(400, 300, density=0.03, seed=5)
    assert pattern.sha256 == expected.sha256
    capsys.readouterr()
    assert _cli(["pattern", "stats", str(out), "--json"]) == 0
    stats = json.loads(capsys.readouterr().out)
    assert stats["dot_count"] == pytest.approx(round(0.03 * 400 * 300), abs=5)
    assert stats["sha256"] == expected.sha256


def test_cli_reports_bad_files_without_a_traceback(tmp_path, capsys):
    assert _cli(["pattern", "stats", str(tmp_path / "nope.png")]) == 2
    assert "nope.png: no such file" in capsys.readouterr().err


def test_cli_rig_takes_what_every_rig_option_takes(tmp_path, capsys):
    """`pattern make --rig` and `pattern stats --rig`: a rig file and a generator config, as for generate
    and capture (a preset only, before)."""
    from dotsim.rig.files import rig_file_json
    from dotsim.rig.presets import get_preset

    rig = get_preset("kinect_v1").scaled(0.2)
    (tmp_path / "sensor.json").write_bytes(rig_file_json(rig))
    (tmp_path / "gen.toml").write_text('[rig]\nfile = "sensor.json"\n')
    for spec in ("sensor.json", "gen.toml"):
        out = tmp_path / f"{spec}.png"
        assert _cli(["pattern", "make", "--rig", str(tmp_path / spec), "--n-dots", "50", "-o", str(out)]) == 0
        pattern = load_pattern(out)
        assert (pattern.width, pattern.height) == (rig.projector.width, rig.projector.height)
        assert _cli(["pattern", "stats", str(out), "--rig", str(tmp_path / spec), "--window", "5"]) == 0
        assert "row windows 11x11 px" in capsys.readouterr().out  # 5 camera px, projector f twice camera f
    assert _cli(["pattern", "make", "--rig", str(tmp_path / "none.yaml"), "-o", str(tmp_path / "x.png")]) == 2
    assert "none.yaml: rig file not found" in capsys.readouterr().err
