"""Wall pattern extraction against wall captures rendered by the oracle from a known pattern.

The truth is independent of the code under test: each known projector dot is traced the other way
(projector ray -> wall -> camera pixel) with the closed-form formulas written out here, to decide
which dots the camera sees; recovered projector centres are compared with the known ones.

Tolerance: a median centre error below 0.2 projector px (0.1 camera px at Structure Core's 2
projector px per camera px) keeps the pattern's own error 5x under the 0.5 px disparity threshold
of the o(0.5) metric. Measured with 2% noise and 2 captures: median 0.08 px, p95 0.19 px.
"""

import hashlib
import json
from dataclasses import replace

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

from capture.wall_pattern import WallPatternError, extract_wall_pattern
from dotsim.oracle import expected_pattern_image
from dotsim.patterns import generate_dot_pattern, load_pattern
from dotsim.rig.geometry import rotation_matrix
from dotsim.rig.presets import get_preset

DISTANCE = 1.5  # metres
DOT_SIGMA = 1.6  # projector px: about 0.8 camera px, a dot a 2-px camera pixel grid resolves
# dots at least 4 camera px apart, so neighbouring dots do not merge in the camera image
MIN_SPACING = 8.0


@pytest.fixture(scope="module")
def rig():
    return get_preset("structure_core").scaled(0.25)  # camera 304 x 224, projector 768 x 768


@pytest.fixture(scope="module")
def pattern(rig):
    return generate_dot_pattern(rig.projector.width, rig.projector.height, density=0.006,
                                min_spacing=MIN_SPACING, dot_sigma=DOT_SIGMA, seed=3)


def plane_depth(rig, normal, offset):
    """Planar depth map of the plane n . X = offset (camera frame): z = offset / (n . ray)."""
    cam = rig.camera
    u, v = np.meshgrid(np.arange(cam.width, dtype=float), np.arange(cam.height, dtype=float))
    rays = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], axis=-1)
    return offset / (rays @ np.asarray(normal, float))


def camera_pixels_of_projector_dots(centres, rig, normal, offset):
    """Where each projector dot (x, y) lands in the camera on the plane n . X = offset.

    Projector ray d (projector frame) -> camera frame R^T d from centre t; X = t + s R^T d meets the
    plane at s = (offset - n . t) / (n . R^T d); then the camera pinhole.
    """
    proj, cam = rig.projector, rig.camera
    d = np.stack([(centres[:, 0] - proj.cx) / proj.fx, (centres[:, 1] - proj.cy) / proj.fy,
                  np.ones(len(centres))], axis=1)
    d_cam = d @ np.array(rig.projector_rotation)  # rows: R^T d
    t = np.array(rig.projector_translation)
    n = np.asarray(normal, float)
    s = (offset - n @ t) / (d_cam @ n)
    X = t + s[:, None] * d_cam
    return np.stack([cam.fx * X[:, 0] / X[:, 2] + cam.cx, cam.fy * X[:, 1] / X[:, 2] + cam.cy], axis=1)


def render_captures(rig, pattern, depth, n_captures, noise, seed=0):
    """Projector-on and projector-off frames: oracle dots (peak about 0.8) + ambient + Gaussian noise."""
    dots = expected_pattern_image(depth, rig, pattern.image)
    dots = 0.8 * dots / dots.max()
    rng = np.random.default_rng(seed)
    ambient = 0.1 + 0.05 * rng.random(depth.shape)  # a textured wall under room light
    on = [dots + ambient + rng.normal(0, noise, depth.shape) for _ in range(n_captures)]
    off = [ambient + rng.normal(0, noise, depth.shape) for _ in range(n_captures)]
    return on, off


def match(result, pattern, rig, normal, offset, margin=2.0):
    """(share of visible dots recovered within 0.5 px, errors of those, share of detections that
    are within 0.5 px of some true dot)."""
    camera = camera_pixels_of_projector_dots(pattern.centres, rig, normal, offset)
    visible = ((camera[:, 0] >= margin) & (camera[:, 0] <= rig.camera.width - 1 - margin)
               & (camera[:, 1] >= margin) & (camera[:, 1] <= rig.camera.height - 1 - margin))
    truth = pattern.centres[visible]
    assert len(truth) > 1000
    distance, _ = cKDTree(result.projector_centres).query(truth)
    found = distance < 0.5
    precision = (cKDTree(pattern.centres).query(result.projector_centres)[0] < 0.5).mean()
    return found.mean(), distance[found], precision


def test_flat_wall_recovers_the_known_dots(rig, pattern):
    depth = np.full((rig.camera.height, rig.camera.width), DISTANCE)
    on, off = render_captures(rig, pattern, depth, n_captures=2, noise=0.02)
    result = extract_wall_pattern(on, off, rig, DISTANCE)
    recall, errors, precision = match(result, pattern, rig, (0, 0, 1), DISTANCE)
    assert recall > 0.95
    assert np.median(errors) < 0.2
    assert precision > 0.99
    assert result.pattern.image.shape == (rig.projector.height, rig.projector.width)
    # the measured dot size: pixel footprint removed, converted to projector px
    assert result.dot_sigma == pytest.approx(DOT_SIGMA, rel=0.15)
    # the rendered pattern has its dots where the recovered centres are
    rows = np.round(result.projector_centres[:, 1]).astype(int)
    cols = np.round(result.projector_centres[:, 0]).astype(int)
    assert np.median(result.pattern.image[rows, cols]) > 0.8


def test_cycles_wall_render_recovers_the_known_dots(rig, pattern, tmp_path):
    """The same check on a real Cycles render of a wall (the generator's Blender stage), which
    knows nothing of the oracle. Measured: median error 0.037 projector px at 16 samples (0.14
    at 4, 0.010 at 64: Cycles' anti-aliasing noise), every visible dot recovered."""
    pytest.importorskip("bpy")
    from generator.blender import demo_scenes
    from generator.blender.render import SceneRenderer
    from generator.scene_spec import SceneSpec

    pattern.save_png(tmp_path / "pattern.png")
    spec = demo_scenes.base_spec(rig.to_dict(), str(tmp_path / "pattern.png"), pattern.sha256, samples=16)
    spec["objects"] = [demo_scenes.wall(DISTANCE)]
    with SceneRenderer() as renderer:
        frame = renderer.render(SceneSpec.from_dict(spec))[0]
    np.testing.assert_allclose(frame["depth"], DISTANCE, rtol=1e-6)
    on, off = frame["projector"] + frame["ambient"], frame["ambient"]
    result = extract_wall_pattern([on], [off], rig, DISTANCE)
    recall, errors, precision = match(result, pattern, rig, (0, 0, 1), DISTANCE)
    assert recall > 0.95
    assert np.median(errors) < 0.2
    assert precision > 0.99
    assert result.dot_sigma == pytest.approx(DOT_SIGMA, rel=0.15)


def test_wrong_distance_is_caught_by_the_comparison(rig, pattern):
    """The check can fail: 2 m instead of 1.5 m shifts every dot by f_p b (1/1.5 - 1/2) = 5.9 px."""
    depth = np.full((rig.camera.height, rig.camera.width), DISTANCE)
    on, off = render_captures(rig, pattern, depth, n_captures=1, noise=0.01)
    result = extract_wall_pattern(on, off, rig, 2.0)
    recall, _, _ = match(result, pattern, rig, (0, 0, 1), DISTANCE)
    assert recall < 0.2


def test_tilted_wall_from_a_depth_map_with_a_rotated_projector(rig, pattern):
    rotated = replace(rig, projector_rotation=rotation_matrix(0.01, -0.02, 0.005))
    normal = np.array([0.25, -0.1, 1.0])
    normal /= np.linalg.norm(normal)
    offset = 1.4  # the wall is about 1.4 m away along its normal
    depth = plane_depth(rotated, normal, offset)
    on, off = render_captures(rotated, pattern, depth, n_captures=2, noise=0.02, seed=1)
    result = extract_wall_pattern(on, off, rotated, depth)
    recall, errors, precision = match(result, pattern, rotated, normal, offset)
    assert recall > 0.95
    assert np.median(errors) < 0.2
    assert precision > 0.99


def test_averaging_repeated_captures_lowers_the_error(rig, pattern):
    depth = np.full((rig.camera.height, rig.camera.width), DISTANCE)
    on, off = render_captures(rig, pattern, depth, n_captures=8, noise=0.06, seed=2)
    single = extract_wall_pattern(on[:1], off[:1], rig, DISTANCE)
    averaged = extract_wall_pattern(on, off, rig, DISTANCE)
    _, single_errors, _ = match(single, pattern, rig, (0, 0, 1), DISTANCE)
    recall, averaged_errors, _ = match(averaged, pattern, rig, (0, 0, 1), DISTANCE)
    # noise / sqrt(8): the centre error should fall by about 2.8x
    assert np.median(averaged_errors) < 0.5 * np.median(single_errors)
    assert recall > 0.95


def test_bad_inputs_are_refused(rig, pattern):
    shape = (rig.camera.height, rig.camera.width)
    with pytest.raises(WallPatternError, match="no dots"):
        extract_wall_pattern([np.full(shape, 0.3)], [np.full(shape, 0.3)], rig, DISTANCE)
    with pytest.raises(WallPatternError, match="304 x 224"):
        extract_wall_pattern([np.zeros((10, 12))], None, rig, DISTANCE)
    with pytest.raises(WallPatternError, match="differ in shape"):
        extract_wall_pattern([np.zeros(shape)], [np.zeros((10, 12))], rig, DISTANCE)
    with pytest.raises(WallPatternError, match="positive number of metres"):
        extract_wall_pattern([np.zeros(shape)], None, rig, -1.0)


def run_cli(argv):
    """Run `dotsim capture ...` through the subcommand's own parser (as commands.cli does)."""
    import argparse

    from capture import cli

    parser = argparse.ArgumentParser(prog="dotsim")
    cli.add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


def test_cli_writes_pattern_centres_and_record_from_png_files(tmp_path, rig, pattern, capsys):
    """16-bit PNG files in (quantised as a sensor would save them), pattern + CSV + JSON out; once
    with --distance and once with a millimetre depth-map PNG of the same wall."""
    depth = np.full((rig.camera.height, rig.camera.width), DISTANCE)
    on, off = render_captures(rig, pattern, depth, n_captures=2, noise=0.02)
    for name, images in (("on", on), ("off", off)):
        (tmp_path / name).mkdir()
        for k, image in enumerate(images):
            cv2.imwrite(str(tmp_path / name / f"wall_{k}.png"), np.round(np.clip(image, 0, 1) * 65535)
                        .astype(np.uint16))
    cv2.imwrite(str(tmp_path / "depth.png"), np.full(depth.shape, DISTANCE * 1000, np.uint16))
    for geometry in (["--distance", str(DISTANCE)], ["--depth-map", str(tmp_path / "depth.png")]):
        out = tmp_path / f"pattern{len(geometry[1])}.png"
        assert run_cli(["capture", "pattern", "--wall", str(tmp_path / "on"), "--off",
                        str(tmp_path / "off" / "*.png"), *geometry, "--rig", "structure_core",
                        "--scale", "0.25", "-o", str(out)]) == 0
        printed = capsys.readouterr().out
        assert "2 on / 2 off capture(s)" in printed and "wrote" in printed
        loaded = load_pattern(out, expected_shape=(rig.projector.height, rig.projector.width))
        centres = np.loadtxt(out.with_suffix(".csv"), delimiter=",", skiprows=1)
        record = json.loads(out.with_suffix(".json").read_text())
        assert len(centres) == record["extraction"]["dots_in_projector"]
        assert record["pattern"]["sha256"] == loaded.sha256
        assert record["sources"]["on"][0]["sha256"] == hashlib.sha256(
            (tmp_path / "on" / "wall_0.png").read_bytes()).hexdigest()
        found = cKDTree(pattern.centres).query(centres[:, :2])[0]
        assert np.median(found) < 0.2 and (found < 0.5).mean() > 0.99


def test_cli_reports_bad_input_naming_it(tmp_path, capsys):
    assert run_cli(["capture", "pattern", "--wall", str(tmp_path / "missing"), "--distance", "1.5",
                    "-o", str(tmp_path / "p.png")]) == 2
    assert f"--wall: {tmp_path / 'missing'} does not exist" in capsys.readouterr().err
    assert run_cli(["capture", "pattern", "--wall", str(tmp_path), "--distance", "1.5", "--rig", "nosuch",
                    "-o", str(tmp_path / "p.png")]) == 2
    assert "--rig 'nosuch': neither a preset" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())
