"""Rigs from files (dotsim JSON, OpenCV FileStorage) and from [rig] config keys, with their checks."""

import json
import math

import cv2
import numpy as np
import pytest

from dotsim.rig import PRESET_DIR, PRESETS, Rig, project_to_projector, rotation_matrix
from dotsim.rig_files import RigFileError, check_rig, load_rig_file, rig_file_json
from generator.config import ConfigError, config_from_dict, load_config
from generator.sample_scene import build_rig

# A calibrated-looking rig: off-centre principal points, projector slightly rotated and offset.
ROTATION = rotation_matrix(0.01, -0.02, 0.015)
TRANSLATION = np.array([0.05, 0.003, -0.002])
K1 = np.array([[600.0, 0.0, 318.2], [0.0, 600.0, 241.7], [0.0, 0.0, 1.0]])
K2 = np.array([[1200.0, 0.0, 801.0], [0.0, 1190.0, 598.0], [0.0, 0.0, 1.0]])


def write_storage(path, skip=(), **override):
    """A cv2.stereoCalibrate-style FileStorage file: X_projector = R X_camera + T."""
    R = np.array(ROTATION)
    entries = {"K1": K1, "D1": np.zeros((1, 5)), "K2": K2, "D2": np.zeros((1, 5)), "R": R,
               "T": (-R @ TRANSLATION).reshape(3, 1), "image_size": [640, 480],
               "projector_size": [1600, 1200]}
    entries.update(override)
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in entries.items():
        if key in skip:
            continue
        if isinstance(value, list):
            storage.startWriteStruct(key, cv2.FileNode_SEQ)
            for item in value:
                storage.write("", item)
            storage.endWriteStruct()
        else:
            storage.write(key, value)
    storage.release()
    return path


@pytest.mark.parametrize("suffix", [".yaml", ".json", ".xml"])
def test_opencv_calibration_projects_points_as_cv2_does(tmp_path, suffix):
    rig = load_rig_file(write_storage(tmp_path / f"calib{suffix}")).rig
    assert rig.name == "calib"
    assert (rig.camera.width, rig.camera.height, rig.camera.cx) == (640, 480, 318.2)
    assert (rig.projector.width, rig.projector.fy, rig.projector.cy) == (1600, 1190.0, 598.0)
    np.testing.assert_allclose(rig.t, TRANSLATION, atol=1e-12)
    # independent: cv2.projectPoints with the file's R, T and K2 must give the same projector pixels
    points = np.array([[0.1, -0.2, 1.0], [-0.4, 0.3, 2.5], [0.0, 0.0, 0.7]])
    R = np.array(ROTATION)
    expected, _ = cv2.projectPoints(points, cv2.Rodrigues(R)[0], -R @ TRANSLATION, K2, None)
    xp, yp, _ = project_to_projector(points, rig)
    np.testing.assert_allclose(np.stack([xp, yp], -1), expected.reshape(-1, 2), atol=1e-9)


def test_sizes_as_separate_width_and_height_keys(tmp_path):
    path = tmp_path / "calib.yaml"
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in (("K1", K1), ("K2", K2), ("R", np.eye(3)), ("T", np.array([[-0.05], [0.0], [0.0]]))):
        storage.write(key, value)
    for key, value in (("image_width", 640), ("image_height", 480), ("projector_width", 1600),
                       ("projector_height", 1200), ("max_depth", 6.5)):
        storage.write(key, value)
    storage.write("name", "bench_rig")
    storage.release()
    rig = load_rig_file(path).rig
    assert rig.name == "bench_rig" and rig.max_depth == 6.5 and rig.is_rectified and rig.baseline == 0.05


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_preset_files_and_wrapped_rig_json(tmp_path, name):
    assert load_rig_file(PRESET_DIR / f"{name}.json").rig == PRESETS[name]
    (tmp_path / "bare.json").write_text(json.dumps(PRESETS[name].to_dict()))
    assert load_rig_file(tmp_path / "bare.json").rig == PRESETS[name]
    (tmp_path / "device.json").write_bytes(rig_file_json(PRESETS[name], device={"serial": "x"}))
    assert load_rig_file(tmp_path / "device.json").rig == PRESETS[name]


@pytest.mark.parametrize("change, message", [
    ({"D1": np.array([[0.1, 0, 0, 0, 0]])}, r"D1 = \[0.1, 0.0, 0.0, 0.0, 0.0\] is not zero.*rectif"),
    ({"K2": np.array([[-1200.0, 0, 800], [0, 1200, 600], [0, 0, 1]])}, r"K2 fx = -1200.*positive focal"),
    ({"K1": np.array([[600.0, 0, 700], [0, 600, 240], [0, 0, 1]])}, r"camera cx = 700 is outside the image"),
    ({"R": np.array(rotation_matrix(0, math.pi, 0))}, r"projector points behind the camera"),
    ({"R": np.array(rotation_matrix(0, math.radians(80), 0))}, r"projector's field misses the camera's view"),
    ({"image_size": [640]}, r"image_size = \[640.0\]; allowed: \[width, height\]"),
])
def test_bad_calibrations_name_the_file_and_value(tmp_path, change, message):
    path = write_storage(tmp_path / "calib.yaml", **change)
    with pytest.raises(RigFileError, match=rf"calib.yaml: .*{message}"):
        load_rig_file(path).rig


@pytest.mark.parametrize("skip, allowed", [(("K2",), "K2 or M2 or cameraMatrix2 or projector_matrix"),
                                           (("projector_size",), "projector_size .* or projector_width"),
                                           (("T",), "allowed names: T")])
def test_missing_keys_list_the_allowed_names(tmp_path, skip, allowed):
    with pytest.raises(RigFileError, match=f"calib.yaml: missing .*{allowed}"):
        load_rig_file(write_storage(tmp_path / "calib.yaml", skip=skip)).rig


def test_bad_dotsim_rig_json_names_the_file_and_value(tmp_path):
    rig = PRESETS["kinect_v1"].to_dict()
    rig["camera"]["fx"] = -580.0
    (tmp_path / "rig.json").write_text(json.dumps({"rig": rig}))
    with pytest.raises(RigFileError, match=r"rig.json: rig.camera: fx must be a finite positive number, "
                       r"got -580.0"):
        load_rig_file(tmp_path / "rig.json").rig
    rig = PRESETS["kinect_v1"].to_dict()
    rig["projector_translation"] = [0.075, 0.0, -2.0]
    (tmp_path / "rig.json").write_text(json.dumps(rig))
    with pytest.raises(RigFileError, match=r"rig.json: the projector sits 2 m behind the camera"):
        load_rig_file(tmp_path / "rig.json").rig


def test_unreadable_rig_files(tmp_path):
    with pytest.raises(RigFileError, match="nope.json: rig file not found"):
        load_rig_file(tmp_path / "nope.json").rig
    (tmp_path / "rig.txt").write_text("{}")
    with pytest.raises(RigFileError, match=r"rig.txt: not a rig file; allowed: .json, .yaml"):
        load_rig_file(tmp_path / "rig.txt").rig
    (tmp_path / "bad.yaml").write_text("just: [text\n")
    with pytest.raises(RigFileError, match="bad.yaml: neither a dotsim rig nor an OpenCV FileStorage"):
        load_rig_file(tmp_path / "bad.yaml").rig


def test_config_rig_file_is_relative_to_the_config_and_equals_the_preset(tmp_path):
    (tmp_path / "rigs").mkdir()
    (tmp_path / "rigs" / "mine.json").write_bytes(rig_file_json(PRESETS["kinect_v1"]))
    (tmp_path / "a.toml").write_text('[rig]\nfile = "rigs/mine.json"\nscale = 0.5\nmax_depth = 7.0\n')
    from_file = build_rig(load_config(tmp_path / "a.toml"))
    preset = {"preset": "kinect_v1", "scale": 0.5, "max_depth": 7.0}
    from_preset = build_rig(config_from_dict({"rig": preset}))
    assert from_file == from_preset and from_file.camera.width == 320


def test_config_explicit_intrinsics_and_pose():
    rig = build_rig(config_from_dict({"rig": {
        "camera_width": 320, "camera_height": 240, "camera_fx": 300.0,
        "projector_width": 800, "projector_height": 600, "projector_fx": 610.0, "projector_fy": 600.0,
        "projector_cx": 401.0, "projector_cy": 300.0, "baseline": 0.04, "projector_z": -0.001,
        "projector_rotation_y": 1.5, "max_depth": 5.0}}))
    assert (rig.camera.width, rig.camera.fy, rig.camera.cx, rig.camera.cy) == (320, 300.0, 159.5, 119.5)
    assert (rig.projector.fx, rig.projector.fy, rig.projector.cx) == (610.0, 600.0, 401.0)
    assert rig.projector_translation == (0.04, 0.0, -0.001) and rig.max_depth == 5.0
    np.testing.assert_allclose(rig.R, np.array(rotation_matrix(0, math.radians(1.5), 0)))


@pytest.mark.parametrize("rig, message", [
    ({"camera_width": 320, "camera_fx": 300.0}, r"explicit camera needs camera_height as well"),
    ({"camera_width": 320, "camera_height": 240, "camera_fx": 300.0, "camera_fy": 301.0},
     r"camera fx = 300 differs from fy = 301.*square pixels"),
    ({"camera_width": 320, "camera_height": 240, "camera_fx": 300.0, "camera_cx": 400.0, "camera_cy": 1.0},
     r"camera cx = 400 is outside the image"),
    ({"file": "missing.yaml"}, r" file: .*missing.yaml: rig file not found"),
])
def test_config_rig_errors_name_the_key(rig, message):
    with pytest.raises(ConfigError, match=rf"<dict>: \[rig\].*{message}"):
        config_from_dict({"rig": rig})


def test_check_rig_accepts_every_preset():
    for rig in PRESETS.values():
        check_rig(rig, "preset")
    assert isinstance(PRESETS["structure_core"], Rig)
