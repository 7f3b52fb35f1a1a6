"""`dotsim capture import / record / pattern / info` with a read-only or full output folder: one line
naming the path, exit status 1, nothing half-written (issue 37, item 1). Real files in: PNG frame
pairs, and an FFV1 video through the OpenCV backend."""

from __future__ import annotations

import pytest

from commands.cli import main
from dotsim.oracle_dataset import make_dataset
from dotsim.rig.files import rig_file_json
from dotsim.rig.presets import get_preset
from tests.capture_inputs import write_on_off_frames
from tests.output_folders import assert_one_line_error, leftovers

RIG = get_preset("structure_core").scaled(0.1)  # camera 122 x 90


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """Two on/off PNG pairs, a 4-frame lossless video and the rig file, of RIG's camera."""
    root = tmp_path_factory.mktemp("inputs")
    write_on_off_frames(root, (RIG.camera.height, RIG.camera.width), seed=3, video=root / "ir.avi")
    (root / "rig.json").write_bytes(rig_file_json(RIG))
    return root


def commands(inputs, out):
    return {
        "import": ["capture", "import", "--on", str(inputs / "on"), "--off", str(inputs / "off"),
                   "--rig", str(inputs / "rig.json"), "--frames-per-scene", "2", "--out", str(out)],
        "record": ["capture", "record", "--device", f"opencv:{inputs / 'ir.avi'}", "--rig",
                   str(inputs / "rig.json"), "--out", str(out), "--scenes", "1", "--frames", "2",
                   "--no-progress", "--no-preview"],
        "pattern": ["capture", "pattern", "--wall", str(inputs / "on"), "--distance", "1.5", "-o",
                    str(out / "pattern.png")],
        "info": ["capture", "info", "--device", f"opencv:{inputs / 'ir.avi'}", "-o", str(out / "rig.json")],
    }


@pytest.mark.parametrize("command", ["import", "record", "pattern", "info"])
def test_a_read_only_output_folder_is_checked_first(command, inputs, read_only_folder, capsys):
    """Checked before a frame is read or a device opened (pattern's walls and info's device would fail
    on their own here: the folder is named first)."""
    assert main(commands(inputs, read_only_folder)[command]) == 1
    assert_one_line_error(capsys.readouterr().err, read_only_folder, "is not writable")
    assert not any(read_only_folder.iterdir())


@pytest.mark.parametrize("command", ["import", "record"])
def test_a_full_output_folder_is_one_line_and_leaves_nothing_half_written(command, inputs, tmp_path,
                                                                          no_space, capsys):
    out = tmp_path / "data"
    assert main(commands(inputs, out)[command]) == 1
    assert_one_line_error(capsys.readouterr().err, out, "no space left on device")
    assert not leftovers(tmp_path) and not list(out.glob("shard_*/scene_*"))


def test_record_refuses_a_dataset_of_rendered_scenes(inputs, tmp_path, capsys):
    """A dataset holds one kind of data (issue 37, item 4)."""
    data = make_dataset(tmp_path / "rendered", scenes=1, frames_per_scene=1)
    assert main(commands(inputs, data)["record"]) == 2
    assert_one_line_error(capsys.readouterr().err, f"{data}: holds a dotsim dataset of rendered scenes")
