"""`dotsim rig show`: the resolved rig of a config, preset or rig file, part by part with its sources."""

import pytest

from commands.cli import main
from dotsim.rig.presets import get_preset
from dotsim.rig.report import field_of_view
from tests.capture.test_capture_rectify import ros_camera_info


def test_a_built_in_config_as_generate_renders_it(capsys):
    assert main(["rig", "show", "tiny"]) == 0
    lines = capsys.readouterr().out.splitlines()
    camera = get_preset("structure_core").scaled(0.1).camera
    h, v = field_of_view(camera)
    assert lines[0] == (f"rig structure_core: camera 122 x 90 px, f {camera.fx:.2f} px, field of view "
                        f"{h:.1f} x {v:.1f} deg; projector 307 x 307 px, f 223.09 px, field of view 69.1 x "
                        "69.1 deg; baseline +0.0634 m; max depth 20 m")
    assert "as `dotsim generate --config tiny` renders it" in lines[1] and "scale 0.1" in lines[1]
    assert lines[3].startswith("camera ") and lines[3].endswith("[from preset structure_core]")
    assert lines[-1].startswith("max depth ") and "tiny.toml: [rig] max_depth]" in lines[-1]


def test_a_config_needs_only_its_rig_table(tmp_path, monkeypatch, capsys):
    """In an empty folder (no assets_cache/ for the built-in config's [assets] cache_dir), and for a
    config whose other tables name files that do not exist: the rig is all `rig show` reads."""
    monkeypatch.chdir(tmp_path)
    assert list(tmp_path.iterdir()) == []
    assert main(["rig", "show", "structure_core"]) == 0
    lines = capsys.readouterr().out.splitlines()
    camera = get_preset("structure_core").camera
    h, v = field_of_view(camera)
    assert lines[0].startswith(f"rig structure_core: camera 1216 x 896 px, f {camera.fx:.2f} px, field of "
                               f"view {h:.1f} x {v:.1f} deg;")
    assert "as `dotsim generate --config structure_core` renders it" in lines[1]
    assert "scale 1)" in lines[1]
    assert lines[-1].startswith("max depth      20 m")
    assert lines[-1].endswith("structure_core.toml: [rig] max_depth]")
    (tmp_path / "mine.toml").write_text('[rig]\npreset = "kinect_v1"\nmax_depth = 6.0\n\n[assets]\n'
                                        'source = "cache"\ncache_dir = "nowhere"\n\n[pattern]\n'
                                        'source = "file"\npath = "missing.png"\n')
    assert main(["rig", "show", "mine.toml"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("rig kinect_v1: camera 640 x 480 px, f 580.00 px") and "max depth 6 m" in out


def test_a_camera_file_with_a_preset_projector(tmp_path, capsys):
    ros = ros_camera_info(tmp_path / "ir.yaml")
    assert main(["rig", "show", "kinect_v1", "--camera-file", str(ros)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("rig ir_camera (camera) + kinect_v1 (projector): camera 320 x 240 px, f 260.00 px")
    assert f"[from {ros}]" in out and "[from preset kinect_v1]" in out
    lens = next(line for line in out.splitlines() if line.startswith("  lens "))
    assert "radtan distortion [-0.28, 0.09, 0.0015, -0.001, 0.0], fx 262.00 fy 258.00" in lens
    assert f"note: {ros} calibrates the camera alone" in out
    assert main(["rig", "show", str(ros)]) == 0  # as --rig takes it: the default preset's projector
    assert capsys.readouterr().out.startswith("rig ir_camera (camera) + structure_core (projector)")


@pytest.mark.parametrize("target, message", [
    ("nosuch", "rig show 'nosuch': neither a preset"),
    ("missing.yaml", "rig show {tmp_path}/missing.yaml: rig file not found"),
])
def test_bad_targets_are_one_line(tmp_path, monkeypatch, capsys, target, message):
    monkeypatch.chdir(tmp_path)
    assert main(["rig", "show", target]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message.format(tmp_path=tmp_path) in err
