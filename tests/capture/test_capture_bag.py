"""`capture import --bag`: a RealSense recording that the test writes itself with pyrealsense2's
recorder over a software_device (tests/capture/realsense_software.py), imported and read back.

pyrealsense2 2.56 and later record ROS2 bags (.db3) only: its recorder refuses any other name
("Output file must have .db3 extension"), so no ROS1 .bag, the RealSense Viewer's format before
2.56, can be written here. Both are opened by the same `context.load_device` call the import makes
(librealsense picks its ROS1 or ROS2 reader by the file), so the test covers the import's code; a
ROS1 reader problem would be librealsense's.
"""

import gc
import hashlib
import time

import numpy as np
import pytest

from commands.cli import main
from dotsim import dataset
from dotsim.rig.presets import get_preset

rs = pytest.importorskip("pyrealsense2")
from tests.capture.realsense_software import DEPTH_UNITS, SoftwareStereoModule  # noqa: E402

RIG = get_preset("structure_core").scaled(0.1)  # 122 x 90 IR


def poses(count: int):
    rng = np.random.default_rng(7)
    shape = (RIG.camera.height, RIG.camera.width)
    return [(rng.integers(100, 256, shape, dtype=np.uint8), rng.integers(0, 60, shape, dtype=np.uint8),
             np.full(shape, 1000 + 250 * k, np.uint16)) for k in range(count)]


def record_bag(path, frames, switch: bool, right=None):
    """Record the software module's streams (left and right IR, depth) into `path`; with `switch` the
    emitter goes off and on again once per pose, so every pose has on frames then off frames. right:
    per pose the right IR's (on, off) images (default: the left ones)."""
    module = SoftwareStereoModule(RIG, frames, stream_right=True, right_poses=right)
    recorder = rs.recorder(str(path), module.device)
    sensor = recorder.query_sensors()[0]
    sensor.open(list(sensor.get_stream_profiles()))
    queue = rs.frame_queue(1000)
    sensor.start(queue)
    with module:
        if switch:
            for k in range(2 * len(frames)):
                time.sleep(0.08)
                module.sensor.set_option(rs.option.emitter_enabled, float(k % 2))
        time.sleep(0.15)
    sensor.stop()
    sensor.close()
    del sensor, recorder, queue
    gc.collect()  # the recorder writes the file's end when it is destroyed
    return module


def read_back(out):
    scenes = [dataset.read_scene(ref.path) for ref in dataset.open_dataset(out).scenes]
    return scenes, [frame for scene in scenes for frame in scene.frames]


def test_recorder_writes_no_ros1_bag(tmp_path):
    module = SoftwareStereoModule(RIG, poses(1))
    with pytest.raises(RuntimeError, match=r"must have \.db3 extension"):
        rs.recorder(str(tmp_path / "x.bag"), module.device)


def test_import_recording_with_emitter_switching(tmp_path, capsys):
    frames = poses(3)
    bag = tmp_path / "rec.db3"
    record_bag(bag, frames, switch=True)
    assert main(["capture", "import", "--bag", str(bag), "--out", str(tmp_path / "data"),
                 "--frames-per-scene", "2"]) == 0
    assert "imported 3 poses" in capsys.readouterr().out
    scenes, stored = read_back(tmp_path / "data")
    assert [len(scene.frames) for scene in scenes] == [2, 1]
    for (on, off, depth), frame in zip(frames, stored, strict=True):
        np.testing.assert_array_equal(frame["ir"], (on / 255.0).astype(np.float16))
        np.testing.assert_array_equal(frame["ambient"], (off / 255.0).astype(np.float16))
        np.testing.assert_allclose(frame["device_depth"], depth * DEPTH_UNITS, rtol=1e-6)
        assert frame["visibility"].mean() > 0.3  # on frames are brighter everywhere
    meta = scenes[0].meta
    # the rig of the recorded calibration: the IR intrinsics, the projector at the right IR camera
    camera = meta["rig"]["camera"]  # librealsense stores intrinsics as float32
    assert camera.keys() == RIG.camera.to_dict().keys()
    np.testing.assert_allclose([camera[key] for key in sorted(camera)],
                               [RIG.camera.to_dict()[key] for key in sorted(camera)], rtol=1e-6)
    np.testing.assert_allclose(meta["rig"]["projector_translation"], [RIG.baseline, 0, 0], atol=1e-6)
    device = meta["capture"]["device"]
    assert device["kind"] == "realsense-recording"
    assert device["sha256"] == hashlib.sha256(bag.read_bytes()).hexdigest()
    sources = meta["capture"]["frames"]
    assert [source["on"]["emitter"] for source in sources] == [True, True]
    assert [source["off"]["emitter"] for source in sources] == [False, False]
    numbers = [source[state]["frame_number"] for source in sources for state in ("on", "off")]
    assert numbers == sorted(numbers)


def test_import_recording_of_both_ir_streams(tmp_path, capsys):
    """--stereo: the recording's infrared 2 frames of the same frame numbers come back as ir_right,
    and its extrinsics in scene.json."""
    frames = poses(2)
    right = [(np.roll(on, -4, axis=1), np.roll(off, -4, axis=1)) for on, off, _ in frames]
    bag = tmp_path / "pair.db3"
    record_bag(bag, frames, switch=True, right=right)
    assert main(["capture", "import", "--bag", str(bag), "--stereo", "--out", str(tmp_path / "data"),
                 "--frames-per-scene", "2"]) == 0
    assert "channels ir, ir_right, ambient, visibility, device_depth" in capsys.readouterr().out
    scenes, stored = read_back(tmp_path / "data")
    for (on, _, _), (right_on, _), frame in zip(frames, right, stored, strict=True):
        np.testing.assert_array_equal(frame["ir"], (on / 255.0).astype(np.float16))
        np.testing.assert_array_equal(frame["ir_right"], (right_on / 255.0).astype(np.float16))
    translation = scenes[0].meta["capture"]["device"]["right_ir"]["extrinsics_from_left"]["translation"]
    np.testing.assert_allclose(translation, [-RIG.baseline, 0.0, 0.0], rtol=1e-6)


def test_import_recording_without_switching_and_with_a_preset_rig(tmp_path, capsys):
    frames = poses(1)
    bag = tmp_path / "on_only.db3"
    module = record_bag(bag, frames, switch=False)
    assert main(["capture", "import", "--bag", str(bag), "--out", str(tmp_path / "data"), "--rig",
                 "structure_core", "--scale", "0.1", "--frames-per-scene", "100"]) == 0
    scenes, stored = read_back(tmp_path / "data")
    assert sorted(scenes[0].meta["channels"]) == ["device_depth", "ir"]
    assert 5 <= len(stored) <= module.pushed  # every recorded IR frame is a pose
    for frame in stored:
        np.testing.assert_array_equal(frame["ir"], (frames[0][0] / 255.0).astype(np.float16))
    assert scenes[0].meta["rig"] == RIG.to_dict()


def test_import_recording_errors(tmp_path, capsys):
    (tmp_path / "junk.bag").write_bytes(b"not a bag\n")
    for args, message in (
            (["--bag", str(tmp_path / "junk.bag")], "junk.bag: pyrealsense2 cannot play it back"),
            (["--bag", str(tmp_path / "missing.db3")], "missing.db3: file not found"),
            (["--bag", str(tmp_path / "rec.mp4")], "rec.mp4: not a RealSense recording; allowed: .bag, .db3"),
            (["--bag", str(tmp_path / "junk.bag"), "--off", "x"], "--bag: leave out --off"),
            (["--on", "x", "--off", "y", "--stereo"], "--stereo is for --bag; with --on, give the right "
             "camera's frames: --right"),
            (["--on", "x"], "--on needs --off")):
        assert main(["capture", "import", *args, "--out", str(tmp_path / "data")]) == 2
        assert message in capsys.readouterr().err
    assert not (tmp_path / "data").exists()
