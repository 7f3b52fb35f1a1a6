"""`capture import`: real image files in, a dotsim dataset out, read back with dotsim.dataset.

Pixel values are checked against the files' own integers (value / white level, rounded to the
format's half float), checksums against hashlib on the file bytes, and the visibility mask
against the projector's reach computed by the oracle with an all-white pattern.
"""

import argparse
import hashlib
import json

import cv2
import numpy as np
import OpenEXR
import pytest

from capture import cli
from capture.dots import capture_visibility
from capture.frames import CaptureError
from capture.import_frames import CAPTURE_CHANNELS, PAIR_CHANNELS, import_frames
from dotsim.dataset import open_dataset
from dotsim.oracle import expected_pattern_image
from dotsim.oracle_dataset import make_dataset
from dotsim.patterns import generate_dot_pattern
from dotsim.rig.presets import get_preset


@pytest.fixture(scope="module")
def rig():
    return get_preset("structure_core").scaled(0.1)  # camera 122 x 90


def write_exr(path, image):
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                 {"Y": image.astype(np.float32)}).write(str(path))


def write_frames(folder, images, suffix=".png"):
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for k, image in enumerate(images):
        path = folder / f"frame_{k}{suffix}"
        if suffix == ".exr":
            write_exr(path, image)
        else:
            assert cv2.imwrite(str(path), image)
        paths.append(path)
    return paths


def random_frames(rig, n, dtype, seed):
    rng = np.random.default_rng(seed)
    shape = (rig.camera.height, rig.camera.width)
    if dtype == np.float32:
        return [rng.random(shape, dtype=np.float32) * 3 for _ in range(n)]
    return [rng.integers(0, np.iinfo(dtype).max, shape, endpoint=True).astype(dtype) for _ in range(n)]


@pytest.mark.parametrize("dtype, suffix, white", [(np.uint16, ".png", 65535.0), (np.uint8, ".png", 255.0),
                                                   (np.float32, ".exr", 1.0)])
def test_import_round_trip(tmp_path, rig, dtype, suffix, white):
    on = random_frames(rig, 8, dtype, seed=1)
    off = random_frames(rig, 8, dtype, seed=2)
    on_paths = write_frames(tmp_path / "on", on, suffix)
    off_paths = write_frames(tmp_path / "off", off, suffix)
    summary = import_frames(str(tmp_path / "on"), str(tmp_path / "off"), rig, tmp_path / "data",
                            frames_per_scene=4, progress=False)
    assert summary["scenes"] == 2 and summary["written"] == 2 and summary["frames"] == 8
    data = open_dataset(tmp_path / "data")
    assert len(data) == 2
    for s in range(2):
        scene = data.read_scene(s)
        meta = scene.meta
        assert meta["has_ground_truth"] is False and meta["source"] == "capture"
        assert sorted(meta["channels"]) == sorted(CAPTURE_CHANNELS)
        assert meta["rig"] == rig.to_dict()
        assert meta["capture"]["white_level"] == white
        for f, frame in enumerate(scene.frames):
            k = 4 * s + f
            assert set(frame) == set(CAPTURE_CHANNELS)
            expected_ir = (on[k].astype(np.float64) / white).astype(np.float16)
            expected_ambient = (off[k].astype(np.float64) / white).astype(np.float16)
            np.testing.assert_array_equal(frame["ir"], expected_ir)
            np.testing.assert_array_equal(frame["ambient"], expected_ambient)
            sources = meta["capture"]["frames"][f]
            assert sources["on"]["path"] == str(on_paths[k].resolve())
            assert sources["on"]["sha256"] == hashlib.sha256(on_paths[k].read_bytes()).hexdigest()
            assert sources["off"]["sha256"] == hashlib.sha256(off_paths[k].read_bytes()).hexdigest()


def test_frames_pair_in_natural_order_from_globs(tmp_path, rig):
    """on_2 pairs with off_2 and frame 10 sorts after frame 9, in one folder matched by globs."""
    frames = random_frames(rig, 11, np.uint16, seed=3)
    folder = tmp_path / "mixed"
    folder.mkdir()
    for k, image in enumerate(frames):
        cv2.imwrite(str(folder / f"on_{k}.png"), image)
        cv2.imwrite(str(folder / f"off_{k}.png"), 65535 - image)
    import_frames(str(folder / "on_*.png"), str(folder / "off_*.png"), rig, tmp_path / "data",
                  frames_per_scene=1, progress=False)
    data = open_dataset(tmp_path / "data")
    for k in range(11):
        frame = data.read_scene(k).frames[0]
        np.testing.assert_array_equal(frame["ir"], (frames[k] / 65535.0).astype(np.float16))
        np.testing.assert_array_equal(frame["ambient"], ((65535 - frames[k]) / 65535.0).astype(np.float16))


def test_visibility_matches_the_projectors_reach(rig):
    """A box in front of a wall casts a projector shadow; the on/off mask must find it.

    Truth: the oracle's image of an all-white pattern is > 0 exactly where the projector reaches.
    Pixels within 2 px of the truth's boundary are left out (dots are blurred over about that).
    The wall is 2.9x farther than the box, so its dots are 8x dimmer (1/r^2), still above the
    relative threshold (5% of the brightest); a much dimmer wall would be "not visible" by
    design, as in the simulator's visibility mask.
    """
    rig = get_preset("structure_core").scaled(0.25)
    shape = (rig.camera.height, rig.camera.width)
    depth = np.full(shape, 2.0)
    # the projector is at +x, so the shadow falls on the wall left of the box: 16 px wide
    depth[30:200, 60:200] = 0.7
    pattern = generate_dot_pattern(rig.projector.width, rig.projector.height, density=0.02,
                                   min_spacing=4.0, dot_sigma=1.2, seed=0)
    dots = expected_pattern_image(depth, rig, pattern.image)
    reach = expected_pattern_image(depth, rig, np.ones_like(pattern.image)) > 0
    assert 0.03 < (~reach).mean() < 0.3  # the scene has a real shadow
    rng = np.random.default_rng(0)
    ambient = 0.05 + 0.02 * rng.random(shape)
    on = ambient + 0.7 * dots / dots.max() + rng.normal(0, 0.01, shape)
    off = ambient + rng.normal(0, 0.01, shape)
    visible = capture_visibility(on, off, window=7)
    square = np.ones((5, 5), np.uint8)
    boundary = cv2.dilate(reach.astype(np.uint8), square) != cv2.erode(reach.astype(np.uint8), square)
    assert (visible == reach)[~boundary].mean() > 0.99
    assert (~visible)[~reach & ~boundary].mean() > 0.99  # the shadow is found, not bridged


def test_bad_inputs_name_the_file_and_write_nothing(tmp_path, rig):
    on = write_frames(tmp_path / "on", random_frames(rig, 4, np.uint16, 1))
    write_frames(tmp_path / "off", random_frames(rig, 4, np.uint16, 2))
    out = tmp_path / "data"

    def refused(on_spec, off_spec, match, **kwargs):
        with pytest.raises(CaptureError, match=match):
            import_frames(str(on_spec), str(off_spec), rig, out, progress=False, **kwargs)
        assert not out.exists()

    refused(tmp_path / "nowhere", tmp_path / "off", "--on frames: .*nowhere does not exist")
    refused(tmp_path / "on", tmp_path / "off" / "*.exr", r"--off frames: no files match .*\*\.exr")
    write_frames(tmp_path / "off3", random_frames(rig, 3, np.uint16, 2))
    refused(tmp_path / "on", tmp_path / "off3", "4 projector-on frames .* but 3 projector-off")
    refused(tmp_path / "on", tmp_path / "off", "do not split into scenes of 3", frames_per_scene=3)

    small = write_frames(tmp_path / "small", [np.zeros((20, 30), np.uint16)] * 4)
    refused(tmp_path / "on", tmp_path / "small", f"{small[0]}: image is 30 x 20 px but rig .* is 122 x 90")

    broken = tmp_path / "broken"
    write_frames(broken, random_frames(rig, 4, np.uint16, 2))
    (broken / "frame_2.png").write_bytes(b"not a png at all")
    refused(tmp_path / "on", broken, f"{broken / 'frame_2.png'}: not a readable PNG")

    colour = tmp_path / "colour"
    write_frames(colour, [np.dstack([f, f // 2, f]) for f in random_frames(rig, 4, np.uint8, 4)])
    refused(tmp_path / "on", colour, f"{colour / 'frame_0.png'}: colour image")

    eight = write_frames(tmp_path / "eight", random_frames(rig, 4, np.uint8, 5))
    refused(tmp_path / "on", tmp_path / "eight", f"{eight[0]}: sample type uint8 differs from {on[0]}")

    nan_exr = tmp_path / "nan"
    images = random_frames(rig, 4, np.float32, 6)
    images[1][3, 4] = np.nan
    write_frames(nan_exr, images, ".exr")
    refused(nan_exr, nan_exr, "is listed both")
    write_frames(tmp_path / "exr", random_frames(rig, 4, np.float32, 7), ".exr")
    refused(nan_exr, tmp_path / "exr", f"{nan_exr / 'frame_1.exr'}: image contains 1 NaN/inf")


def test_rerun_resumes_and_refuses_other_files(tmp_path, rig):
    write_frames(tmp_path / "on", random_frames(rig, 4, np.uint16, 1))
    write_frames(tmp_path / "off", random_frames(rig, 4, np.uint16, 2))
    args = (str(tmp_path / "on"), str(tmp_path / "off"), rig, tmp_path / "data")
    first = import_frames(*args, frames_per_scene=1, progress=False)
    assert (first["written"], first["skipped"]) == (4, 0)
    # a crashed run leaves a scene missing and a temp dir: the rerun writes only that scene
    scene = open_dataset(tmp_path / "data").scenes[2].path
    temp = scene.parent / ".tmp-scene_0000002-999999999"
    scene.rename(temp)
    again = import_frames(*args, frames_per_scene=1, progress=False)
    assert (again["written"], again["skipped"]) == (1, 3)
    assert not temp.exists()
    assert len(open_dataset(tmp_path / "data")) == 4
    # different recordings into the same dataset are refused, naming the scene
    write_frames(tmp_path / "other", random_frames(rig, 4, np.uint16, 9))
    with pytest.raises(CaptureError, match="scene_0000000: was imported from other files"):
        import_frames(str(tmp_path / "other"), str(tmp_path / "off"), rig, tmp_path / "data",
                      frames_per_scene=1, progress=False)


def test_cli_import_records_settings_and_pattern(tmp_path, rig, capsys):
    write_frames(tmp_path / "on", random_frames(rig, 2, np.uint16, 1))
    write_frames(tmp_path / "off", random_frames(rig, 2, np.uint16, 2))
    (tmp_path / "settings.json").write_text(json.dumps({"exposure_us": 1600, "gain": 2}))
    pattern = generate_dot_pattern(rig.projector.width, rig.projector.height, seed=5)
    pattern.save_png(tmp_path / "pattern.png")
    parser = argparse.ArgumentParser(prog="dotsim")
    cli.add_parser(parser.add_subparsers(dest="command", required=True))
    argv = ["capture", "import", "--on", str(tmp_path / "on"), "--off", str(tmp_path / "off"),
            "--scale", "0.1", "--out", str(tmp_path / "data"), "--frames-per-scene", "2",
            "--white-level", "1023", "--settings", str(tmp_path / "settings.json"),
            "--pattern", str(tmp_path / "pattern.png")]
    args = parser.parse_args(argv)
    assert args.func(args) == 0
    out, err = capsys.readouterr()
    assert "imported 2 frame pairs as 1 scene(s)" in out and "importing scenes" in err  # the bar
    quiet = [str(tmp_path / "quiet") if arg == str(tmp_path / "data") else arg for arg in argv]
    args = parser.parse_args([*quiet, "--no-progress"])
    assert args.func(args) == 0
    out, err = capsys.readouterr()
    assert "imported 2 frame pairs" in out and "importing scenes" not in err and "checking frames" not in err
    data = open_dataset(tmp_path / "data")
    meta = data.read_scene(0).meta
    assert meta["capture"]["settings"] == {"exposure_us": 1600, "gain": 2}
    assert meta["capture"]["white_level"] == 1023
    assert meta["pattern"]["sha256"] == pattern.sha256
    assert (tmp_path / "data" / "pattern.png").read_bytes() == (tmp_path / "pattern.png").read_bytes()
    assert "pattern.png" in data.index["files"]
    # a pattern of the wrong size for the rig is refused, naming the file
    args = parser.parse_args(argv[:-1] + [str(tmp_path / "small.png")])
    generate_dot_pattern(50, 40, seed=1).save_png(tmp_path / "small.png")
    assert args.func(args) == 2
    assert f"{tmp_path / 'small.png'}: pattern is 50x40" in capsys.readouterr().err


def test_import_of_a_stereo_pair_stores_the_right_ir(tmp_path, rig):
    """--right: the right camera's projector-on frames, paired in order with --on, come back as
    ir_right (value / white level), their files and checksums in scene.json; a rerun from other right
    files is refused; a count mismatch, or a rig without a second camera, writes nothing."""
    write_frames(tmp_path / "on", random_frames(rig, 4, np.uint16, 1))
    write_frames(tmp_path / "off", random_frames(rig, 4, np.uint16, 2))
    right = random_frames(rig, 4, np.uint16, 3)
    right_paths = write_frames(tmp_path / "right", right)
    summary = import_frames(str(tmp_path / "on"), str(tmp_path / "off"), rig, tmp_path / "data",
                            frames_per_scene=2, progress=False, right_spec=str(tmp_path / "right"))
    assert summary["written"] == 2
    data = open_dataset(tmp_path / "data")
    for s in range(2):
        scene = data.read_scene(s)
        assert sorted(scene.meta["channels"]) == sorted(PAIR_CHANNELS)
        assert scene.meta["format_version"] == "2.1"
        for f, frame in enumerate(scene.frames):
            k = 2 * s + f
            np.testing.assert_array_equal(frame["ir_right"],
                                          (right[k].astype(np.float64) / 65535).astype(np.float16))
            source = scene.meta["capture"]["frames"][f]["right"]
            assert source == {"path": str(right_paths[k].resolve()),
                              "sha256": hashlib.sha256(right_paths[k].read_bytes()).hexdigest()}
    write_frames(tmp_path / "other", random_frames(rig, 4, np.uint16, 9))
    with pytest.raises(CaptureError, match="scene_0000000: was imported from other files"):
        import_frames(str(tmp_path / "on"), str(tmp_path / "off"), rig, tmp_path / "data",
                      frames_per_scene=2, progress=False, right_spec=str(tmp_path / "other"))
    write_frames(tmp_path / "right3", random_frames(rig, 3, np.uint16, 3))
    for right_spec, message, chosen in (
            (tmp_path / "right3", "4 projector-on frames .* but 3 right projector-on frames", rig),
            (tmp_path / "right", "--right: rig 'kinect_v1' has no second IR camera",
             get_preset("kinect_v1"))):
        with pytest.raises(CaptureError, match=message):
            import_frames(str(tmp_path / "on"), str(tmp_path / "off"), chosen, tmp_path / "new",
                          progress=False, right_spec=str(right_spec))
        assert not (tmp_path / "new").exists()


def test_import_refuses_a_dataset_of_rendered_scenes(tmp_path, rig, capsys):
    """A dataset holds one kind of data (issue 37, item 4); the folder stays as it was."""
    data = make_dataset(tmp_path / "rendered", scenes=1, frames_per_scene=1)
    before = {p: p.read_bytes() for p in data.rglob("*") if p.is_file()}
    write_frames(tmp_path / "on", random_frames(rig, 2, np.uint16, 1))
    write_frames(tmp_path / "off", random_frames(rig, 2, np.uint16, 2))
    with pytest.raises(CaptureError, match=f"{data}: holds a dotsim dataset of rendered scenes"):
        import_frames(str(tmp_path / "on"), str(tmp_path / "off"), rig, data, frames_per_scene=2,
                      progress=False)
    assert {p: p.read_bytes() for p in data.rglob("*") if p.is_file()} == before
