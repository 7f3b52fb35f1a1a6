"""Rigs from calibration files as people have them (dotsim JSON, OpenCV samples, stereo_calib, ROS
camera_info, Kalibr; fixtures written by cv2.FileStorage here) and from [rig] config keys, with their
checks and every refused key."""

import json
import math

import cv2
import numpy as np
import pytest

from dotsim.rig.calibration_formats import read_calibration
from dotsim.rig.config import RigConfig
from dotsim.rig.files import RigFileError, check_rig, configured_rig, load_rig_file, rig_file_json
from dotsim.rig.geometry import Intrinsics, Rig, project_to_projector, rotation_matrix
from dotsim.rig.presets import PRESET_DIR, PRESETS
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


@pytest.mark.parametrize("max_depth", [None, 0.5, 1000.0, 0.49, 1000.5])
def test_max_depth_of_a_rig_file_has_the_configs_bounds_and_default(tmp_path, max_depth):
    """One bound for max_depth: a calibration file's is held to the config's [rig] max_depth range,
    and a file without one gets the config's default."""
    path = tmp_path / "calib.yaml"
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in (("K1", K1), ("K2", K2), ("R", np.eye(3)), ("T", np.array([[-0.05], [0.0], [0.0]])),
                       ("image_size", np.array([[640, 480]])), ("projector_size", np.array([[1600, 1200]]))):
        storage.write(key, value)
    if max_depth is not None:
        storage.write("max_depth", max_depth)
    storage.release()
    config_rule = RigConfig.__dataclass_fields__["max_depth"]
    if max_depth is None or 0.5 <= max_depth <= 1000.0:
        expected = config_rule.default if max_depth is None else max_depth
        assert load_rig_file(path).rig.max_depth == expected
        config_from_dict({"rig": {"max_depth": expected}})  # the config takes it too
    else:
        with pytest.raises(RigFileError, match=r"max_depth = .*allowed: a number, 0.5 <= x <= 1000"):
            load_rig_file(path)
        with pytest.raises(ConfigError, match=r"max_depth = .*allowed: a number, 0.5 <= x <= 1000"):
            config_from_dict({"rig": {"max_depth": max_depth}})


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_preset_files_and_wrapped_rig_json(tmp_path, name):
    assert load_rig_file(PRESET_DIR / f"{name}.json").rig == PRESETS[name]
    (tmp_path / "bare.json").write_text(json.dumps(PRESETS[name].to_dict()))
    assert load_rig_file(tmp_path / "bare.json").rig == PRESETS[name]
    (tmp_path / "device.json").write_bytes(rig_file_json(PRESETS[name], device={"serial": "x"}))
    assert load_rig_file(tmp_path / "device.json").rig == PRESETS[name]


@pytest.mark.parametrize("change, message", [
    ({"K2": np.array([[-1200.0, 0, 800], [0, 1200, 600], [0, 0, 1]])}, r"K2 fx = -1200.*positive focal"),
    ({"K1": np.array([[600.0, 0, 700], [0, 600, 240], [0, 0, 1]])}, r"camera cx = 700 is outside the image"),
    ({"R": np.array(rotation_matrix(0, math.pi, 0))}, r"projector points behind the camera"),
    ({"R": np.array(rotation_matrix(0, math.radians(80), 0))}, r"projector's field misses the camera's view"),
    ({"image_size": [640]}, r"image_size = \[640.0\]; allowed: \[width, height\]"),
])
def test_bad_calibrations_name_the_file_and_value(tmp_path, change, message):
    path = write_storage(tmp_path / "calib.yaml", **change)
    with pytest.raises(RigFileError, match=rf"calib.yaml: .*{message}"):
        load_rig_file(path)


@pytest.mark.parametrize("skip, allowed", [
    (("K2", "D2", "projector_size"), "missing the projector matrix .K2 or M2 or cameraMatrix2 or "
     "projector_matrix"),
    (("K2",), "D2 without a projector matrix; allowed names of the matrix: K2 or M2"),
    (("projector_size",), "no projector image size.*projector_size"),
    (("T",), "missing the translation .T.")])
def test_missing_keys_list_the_allowed_names(tmp_path, skip, allowed):
    with pytest.raises(RigFileError, match=f"calib.yaml.*{allowed}"):
        load_rig_file(write_storage(tmp_path / "calib.yaml", skip=skip))


def test_bad_dotsim_rig_json_names_the_file_and_value(tmp_path):
    rig = PRESETS["kinect_v1"].to_dict()
    rig["camera"]["fx"] = -580.0
    (tmp_path / "rig.json").write_text(json.dumps({"rig": rig}))
    with pytest.raises(RigFileError, match=r"rig.json: rig.camera.fx = -580.0: out of range; allowed: a "
                       r"number, 0 < x"):
        load_rig_file(tmp_path / "rig.json")
    rig = PRESETS["kinect_v1"].to_dict()
    rig["projector_translation"] = [0.075, 0.0, -2.0]
    (tmp_path / "rig.json").write_text(json.dumps(rig))
    with pytest.raises(RigFileError, match=r"rig.json: the projector sits 2 m behind the camera"):
        load_rig_file(tmp_path / "rig.json")


def test_unreadable_rig_files(tmp_path):
    with pytest.raises(RigFileError, match="nope.json: rig file not found"):
        load_rig_file(tmp_path / "nope.json")
    (tmp_path / "rig.txt").write_text("{}")
    with pytest.raises(RigFileError, match=r"rig.txt: not a rig file; allowed: .json, .yaml"):
        load_rig_file(tmp_path / "rig.txt")
    (tmp_path / "bad.yaml").write_text("just: [text\n")
    with pytest.raises(RigFileError, match="bad.yaml: not valid YAML"):
        load_rig_file(tmp_path / "bad.yaml")
    (tmp_path / "bad.xml").write_text("<opencv_storage><K1>\n")
    with pytest.raises(RigFileError, match="bad.xml: neither a dotsim rig nor an OpenCV FileStorage"):
        load_rig_file(tmp_path / "bad.xml")


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


# ---- the calibration files people have, each written here by cv2.FileStorage ----

def write_file_storage(path, entries: dict, flow=True):
    """A cv2.FileStorage file of nested dicts (maps), lists (sequences), arrays and scalars."""
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)

    def put(key, value):
        if isinstance(value, dict):
            storage.startWriteStruct(key, cv2.FileNode_MAP)
            for k, v in value.items():
                put(k, v)
            storage.endWriteStruct()
        elif isinstance(value, list):
            storage.startWriteStruct(key, cv2.FileNode_SEQ | (cv2.FileNode_FLOW if flow else 0))
            for item in value:
                put("", item)
            storage.endWriteStruct()
        else:
            storage.write(key, value)

    for key, value in entries.items():
        put(key, value)
    storage.release()
    return path


def ros_matrix(array) -> dict:
    """A matrix as ROS camera_info writes it: a mapping of rows, cols and data."""
    array = np.atleast_2d(np.asarray(array, np.float64))
    return {"rows": array.shape[0], "cols": array.shape[1], "data": array.ravel().tolist()}


CAMERA_K = np.array([[602.5, 0.0, 321.3], [0.0, 598.5, 238.9], [0.0, 0.0, 1.0]])
CAMERA_D = np.array([[0.12, -0.25, 0.001, -0.002, 0.08]])


def single_camera_sample(path):
    """What OpenCV's calibration sample (samples/cpp/tutorial_code/calib3d/camera_calibration) writes."""
    return write_file_storage(path, {
        "calibration_time": "Wed Nov 25 00:00:00 2026", "nr_of_frames": 25, "image_width": 640,
        "image_height": 480, "board_width": 9, "board_height": 6, "square_size": 0.025, "flags": 0,
        "fisheye_model": 0, "camera_matrix": CAMERA_K, "distortion_coefficients": CAMERA_D.T,
        "avg_reprojection_error": 0.21, "per_view_reprojection_errors": np.full((25, 1), 0.2, np.float32),
        "extrinsic_parameters": np.zeros((25, 6)), "image_points": np.zeros((25, 54, 2), np.float32),
        "grid_points": np.zeros((1, 54, 3), np.float32)})


def expected_lens_rig(rig, lens):
    """The rig of a calibrated lens: its square pinhole model, (fx + fy) / 2, same principal point."""
    focal = (CAMERA_K[0, 0] + CAMERA_K[1, 1]) / 2
    assert (rig.camera.width, rig.camera.height, rig.camera.fx, rig.camera.fy) == (640, 480, focal, focal)
    assert (rig.camera.cx, rig.camera.cy) == (CAMERA_K[0, 2], CAMERA_K[1, 2])
    np.testing.assert_array_equal(lens.intrinsics.K, CAMERA_K)
    assert lens.distortion == tuple(CAMERA_D.ravel()) and lens.model == "radtan"


def test_single_camera_sample_as_camera_file_with_a_preset_projector(tmp_path):
    single_camera_sample(tmp_path / "camera.yml")
    (tmp_path / "a.toml").write_text('[rig]\npreset = "kinect_v1"\ncamera_file = "camera.yml"\n')
    config = load_config(tmp_path / "a.toml")
    calibrated = configured_rig(config.rig, "a.toml")
    expected_lens_rig(calibrated.rig, calibrated.lens)
    kinect = PRESETS["kinect_v1"]
    assert calibrated.rig.projector == kinect.projector and calibrated.rig.t.tolist() == kinect.t.tolist()
    # the rig says it is the user's camera with the preset's projector, and where each part came from
    assert calibrated.rig.name == "camera (camera) + kinect_v1 (projector)"
    camera_file = str(tmp_path / "camera.yml")
    assert dict(calibrated.sources) == {"camera": camera_file, "projector": "preset kinect_v1",
                                        "pose": "preset kinect_v1", "second camera": "preset kinect_v1",
                                        "max depth": "a.toml max_depth"}
    assert calibrated.notes == (f"{camera_file} calibrates the camera alone: the projector and its pose are "
                                "those of preset kinect_v1 (rig 'camera (camera) + kinect_v1 (projector)')",)
    note = calibrated.rectification_note("a.toml")
    assert note.count("\n") == 0 and "lens distortion" in note and "rectified" in note
    # the generator renders the pinhole model
    assert build_rig(config) == calibrated.rig
    # as a whole rig the file lacks a projector, and says so
    with pytest.raises(RigFileError, match=r"camera.yml: missing the projector matrix .* the rotation \(R\)"):
        load_rig_file(tmp_path / "camera.yml")


ROS_TEXT = """image_width: 640
image_height: 480
camera_name: ir_camera
camera_matrix:
  rows: 3
  cols: 3
  data: [602.5, 0, 321.3, 0, 598.5, 238.9, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0.12, -0.25, 0.001, -0.002, 0.08]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [590, 0, 320, 0, 0, 590, 240, 0, 0, 0, 1, 0]
"""


@pytest.mark.parametrize("writer", ["cv2", "ros"])
def test_ros_camera_info(tmp_path, writer):
    path = tmp_path / "ir_camera.yaml"
    if writer == "ros":  # as camera_calibration writes it: plain YAML, no %YAML:1.0 header
        path.write_text(ROS_TEXT)
    else:
        write_file_storage(path, {
            "image_width": 640, "image_height": 480, "camera_name": "ir_camera",
            "camera_matrix": ros_matrix(CAMERA_K), "distortion_model": "plumb_bob",
            "distortion_coefficients": ros_matrix(CAMERA_D), "rectification_matrix": ros_matrix(np.eye(3)),
            "projection_matrix": ros_matrix(np.hstack([CAMERA_K, np.zeros((3, 1))]))})
    calibrated = configured_rig(config_from_dict({"rig": {"camera_file": str(path)}}).rig, "x")
    expected_lens_rig(calibrated.rig, calibrated.lens)
    assert calibrated.rig.projector == PRESETS["structure_core"].projector


def kalibr_camchain(path, **cam1_change):
    """A Kalibr camchain: cam0 the IR camera, cam1 the projector, T_cn_cnm1 = [R T; 0 1]."""
    R = np.array(ROTATION)
    transform = np.eye(4)
    transform[:3, :3], transform[:3, 3] = R, -R @ TRANSLATION
    cam1 = {"T_cn_cnm1": [row.tolist() for row in transform], "cam_overlaps": [0], "camera_model": "pinhole",
            "distortion_coeffs": [0.0, 0.0, 0.0, 0.0], "distortion_model": "radtan",
            "intrinsics": [K2[0, 0], K2[1, 1], K2[0, 2], K2[1, 2]], "resolution": [1600, 1200],
            "rostopic": "/projector"}
    cam1.update(cam1_change)
    return write_file_storage(path, {
        "cam0": {"cam_overlaps": [1], "camera_model": "pinhole", "distortion_model": "radtan",
                 "distortion_coeffs": CAMERA_D.ravel()[:4].tolist(),
                 "intrinsics": [CAMERA_K[0, 0], CAMERA_K[1, 1], CAMERA_K[0, 2], CAMERA_K[1, 2]],
                 "resolution": [640, 480], "rostopic": "/ir/image_raw"},
        "cam1": cam1})


def test_kalibr_camchain_is_a_whole_rig(tmp_path):
    calibrated = load_rig_file(kalibr_camchain(tmp_path / "camchain.yaml"))
    rig = calibrated.rig
    assert calibrated.lens.distortion == tuple(CAMERA_D.ravel()[:4]) and calibrated.lens.model == "radtan"
    assert rig.projector == Intrinsics(1600, 1200, 1200.0, 1190.0, 801.0, 598.0)
    # independent: cv2.projectPoints with R and T of T_cn_cnm1 and cam1's matrix
    points = np.array([[0.1, -0.2, 1.0], [-0.4, 0.3, 2.5]])
    R = np.array(ROTATION)
    expected, _ = cv2.projectPoints(points, cv2.Rodrigues(R)[0], -R @ TRANSLATION, K2, None)
    xp, yp, _ = project_to_projector(points, rig)
    np.testing.assert_allclose(np.stack([xp, yp], -1), expected.reshape(-1, 2), atol=1e-9)


def test_stereo_calib_pair_with_sizes_from_the_config(tmp_path):
    R = np.array(ROTATION)
    write_file_storage(tmp_path / "intrinsics.yml", {"M1": CAMERA_K, "D1": CAMERA_D, "M2": K2,
                                                      "D2": np.zeros((1, 5))})
    write_file_storage(tmp_path / "extrinsics.yml", {
        "R": R, "T": (-R @ TRANSLATION).reshape(3, 1), "R1": np.eye(3), "R2": np.eye(3),
        "P1": np.zeros((3, 4)), "P2": np.zeros((3, 4)), "Q": np.zeros((4, 4))})
    with pytest.raises(RigFileError, match=r"intrinsics.yml \(with extrinsics.yml\): M1: the file gives no "
                       r"camera image size .*image_size.*camera_width and camera_height"):
        load_rig_file(tmp_path / "intrinsics.yml")
    config = config_from_dict({"rig": {"file": str(tmp_path / "intrinsics.yml"), "camera_width": 640,
                                       "camera_height": 480, "projector_width": 1600,
                                       "projector_height": 1200}})
    calibrated = configured_rig(config.rig, "x")
    expected_lens_rig(calibrated.rig, calibrated.lens)
    np.testing.assert_allclose(calibrated.rig.t, TRANSLATION, atol=1e-12)
    assert calibrated.rig.projector.fy == 1190.0 and calibrated.rig.name == "intrinsics"
    with pytest.raises(ConfigError, match=r"the file gives a 640 x 480 px camera, \[rig\] camera_width / "
                       "camera_height 320 x 240"):
        config_from_dict({"rig": {"file": str(kalibr_camchain(tmp_path / "c.yaml")), "camera_width": 320,
                                  "camera_height": 240}})


def test_camera_file_with_the_projector_of_a_device_rig_file(tmp_path):
    device = PRESETS["realsense_d415"]
    (tmp_path / "sensor.json").write_bytes(rig_file_json(device, device={"serial": "123"}))
    write_file_storage(tmp_path / "cam.xml", {"camera_matrix": CAMERA_K, "distortion_coefficients": CAMERA_D,
                                              "image_width": 640, "image_height": 480})
    calibrated = configured_rig(config_from_dict({"rig": {
        "camera_file": str(tmp_path / "cam.xml"), "projector_file": str(tmp_path / "sensor.json")}}).rig, "x")
    expected_lens_rig(calibrated.rig, calibrated.lens)
    assert calibrated.rig.projector == device.projector and calibrated.rig.t.tolist() == device.t.tolist()


def test_opencv_matrix_with_integer_literals_reads_right(tmp_path):
    # hand-written, as docs/GEOMETRY.md's example: cv2 4.11's FileNode.mat() reads these integers as garbage
    (tmp_path / "rig.yaml").write_text(
        "%YAML:1.0\n"
        "K1: !!opencv-matrix {rows: 3, cols: 3, dt: d, data: [600, 0, 319.5, 0, 600, 239.5, 0, 0, 1]}\n"
        "K2: !!opencv-matrix {rows: 3, cols: 3, dt: d, data: [1200, 0, 799.5, 0, 1200, 599.5, 0, 0, 1]}\n"
        "R: !!opencv-matrix {rows: 3, cols: 3, dt: d, data: [1, 0, 0, 0, 1, 0, 0, 0, 1]}\n"
        "T: !!opencv-matrix {rows: 3, cols: 1, dt: d, data: [-0.05, 0, 0]}\n"
        "image_size: [640, 480]\nprojector_size: [1600, 1200]\n")
    rig = load_rig_file(tmp_path / "rig.yaml").rig
    assert rig.camera == Intrinsics(640, 480, 600.0, 600.0, 319.5, 239.5)
    assert rig.projector == Intrinsics(1600, 1200, 1200.0, 1200.0, 799.5, 599.5)
    assert rig.projector_translation == (0.05, 0.0, 0.0) and rig.is_rectified


@pytest.mark.parametrize("write, message", [
    (lambda p: write_storage(p, foo=3.0), r"key 'foo' is neither read nor a known calibration key"),
    (lambda p: write_storage(p, D2=np.array([[0.01, 0, 0, 0, 0]])),
     r"K2: projector distortion \[0.01, 0.0, 0.0, 0.0, 0.0\] is not zero"),
    (lambda p: write_storage(p, D1=np.array([[0.1, 0.2, 0.0]])),
     r"D1 has 3 coefficients; allowed .* 4, 5, 8"),
    (lambda p: write_storage(p, fisheye_model=2), r"fisheye_model = 2; allowed: 0 or 1"),
    (lambda p: write_file_storage(p, {"camera_matrix": CAMERA_K, "image_width": 640, "image_height": 480,
                                      "distortion_model": "fov"}),
     r"distortion_model = 'fov'; allowed: plumb_bob, radtan"),
    (lambda p: write_file_storage(p, {"camera_matrix": ros_matrix(CAMERA_K), "image_width": 640,
                                      "image_height": 480, "rectification_matrix": ros_matrix(ROTATION)}),
     r"rectification_matrix is not the identity"),
    (lambda p: write_file_storage(p, {"camera_matrix": ros_matrix(CAMERA_K), "image_width": 640}),
     r"image_width and image_height go together"),
    (lambda p: kalibr_camchain(p, camera_model="omni"), r"cam1: camera_model = 'omni'; allowed: pinhole"),
    (lambda p: kalibr_camchain(p, distortion_coeffs=[0.1, 0, 0, 0]), r"projector distortion \[0.1"),
    (lambda p: kalibr_camchain(p, timeshift="x"), r"cam1: key 'timeshift' is neither read"),
    (lambda p: write_file_storage(p, {"cam0": {"camera_model": "pinhole"}, "cam2": {}}),
     r"cameras cam0, cam2; allowed: cam0 .* and optionally cam1"),
])
def test_refused_keys_name_the_file_and_key(tmp_path, write, message):
    path = write(tmp_path / "calib.yaml")
    with pytest.raises(RigFileError, match=rf"calib.yaml.*{message}"):
        load_rig_file(path)


def test_fisheye_lens_from_the_calibration_sample(tmp_path):
    write_file_storage(tmp_path / "fish.yml", {
        "camera_matrix": CAMERA_K, "image_width": 640, "image_height": 480, "fisheye_model": 1,
        "distortion_coefficients": np.array([[0.01, 0.02, 0.0, 0.001]])})
    config = config_from_dict({"rig": {"camera_file": str(tmp_path / "fish.yml")}})
    calibrated = configured_rig(config.rig, "x")
    assert calibrated.lens.model == "fisheye" and calibrated.lens.distortion == (0.01, 0.02, 0.0, 0.001)


def test_square_undistorted_calibration_needs_no_lens(tmp_path):
    assert load_rig_file(write_storage(tmp_path / "calib.yaml")).lens is None
    calibrated = load_rig_file(write_storage(tmp_path / "calib.yaml", K1=CAMERA_K))  # fx != fy, no distortion
    assert calibrated.lens.distortion == () and calibrated.rig.camera.fx == calibrated.rig.camera.fy == 600.5
    assert "fx != fy" in calibrated.rectification_note("x")


# ----------------------------------------------------------------------------- files of bad shape
# (issue 37, item 3) Written as text, as a person or another tool would: each is refused with one
# line naming the file and the key, whichever reader reads it.

K_DATA = "[600, 0, 319.5, 0, 600, 239.5, 0, 0, 1]"
HUGE = "1" + "0" * 400  # a 401-digit integer
OPENCV_YAML = """%YAML:1.0
---
camera_matrix: !!opencv-matrix
   rows: {rows}
   cols: 3
   dt: d
   data: {data}
image_width: 640
image_height: 480
"""
PLAIN_YAML = """camera_matrix:
  rows: {rows}
  cols: 3
  data: {data}
image_width: 640
image_height: 480
"""
JSON = ('{{"camera_matrix": {{"rows": {rows}, "cols": 3, "data": {data}}}, "image_width": 640, '
        '"image_height": 480}}')
LAYOUTS = {"opencv.yaml": OPENCV_YAML, "plain.yaml": PLAIN_YAML, "calib.json": JSON}
ANY_LAYOUT, NOT_OPENCV = tuple(LAYOUTS), ("plain.yaml", "calib.json")  # OpenCV's YAML has no booleans


@pytest.mark.parametrize("name, rows, data, message", [
    *((name, "3", K_DATA.replace("600", HUGE, 1),
       r"camera_matrix(: data)?(: OpenCV cannot read its value| holds a 401-digit integer)")
      for name in ANY_LAYOUT),
    *((name, "3.5", K_DATA, r"camera_matrix: rows 3.5 x cols 3 does not match") for name in ANY_LAYOUT),
    *((name, "true", K_DATA, r"camera_matrix: rows True x cols 3 does not match") for name in NOT_OPENCV),
    *((name, "3", K_DATA.replace("600", "true", 1), r"camera_matrix is not a matrix or a list of numbers")
      for name in NOT_OPENCV),
])
def test_matrix_of_bad_numbers_or_shape(tmp_path, name, rows, data, message):
    path = tmp_path / name
    path.write_text(LAYOUTS[name].format(rows=rows, data=data))
    with pytest.raises(RigFileError, match=rf"^{path}: ({message})") as caught:
        load_rig_file(path)
    assert "\n" not in str(caught.value)


@pytest.mark.parametrize("name, text", [
    ("plain.yaml", PLAIN_YAML.format(rows=3, data=K_DATA) + "image_width: 320\n"),
    ("opencv.yaml", OPENCV_YAML.format(rows=3, data=K_DATA) + "image_width: 320\n"),
    ("calib.xml", '<?xml version="1.0"?>\n<opencv_storage>\n<camera_matrix type_id="opencv-matrix"><rows>3'
     '</rows><cols>3</cols><dt>d</dt><data>600 0 319.5 0 600 239.5 0 0 1</data></camera_matrix>\n'
     "<image_width>640</image_width><image_width>320</image_width><image_height>480</image_height>\n"
     "</opencv_storage>\n"),
    ("calib.json", JSON.format(rows=3, data=K_DATA)[:-1] + ', "image_width": 320}'),
    ("nested.yaml", PLAIN_YAML.format(rows=3, data=K_DATA).replace("  cols: 3\n", "  cols: 3\n  cols: 3\n")),
])
def test_a_key_given_twice_is_refused_by_every_reader(tmp_path, name, text):
    """YAML readers keep the last of two, OpenCV's FileStorage the first: neither may decide."""
    path = tmp_path / name
    path.write_text(text)
    key = "cols" if name.startswith("nested") else "image_width"
    with pytest.raises(RigFileError, match=rf"^{path}: key '{key}' is given twice"):
        load_rig_file(path)


def test_kalibr_transform_must_be_homogeneous(tmp_path):
    R = np.array(ROTATION)
    transform = np.eye(4)
    transform[:3, :3], transform[:3, 3] = R, -R @ TRANSLATION
    transform[3, 3] = 2.0
    path = kalibr_camchain(tmp_path / "camchain.yaml", T_cn_cnm1=[row.tolist() for row in transform])
    with pytest.raises(RigFileError, match=rf"^{path}: cam1: T_cn_cnm1 bottom row \[0.0, 0.0, 0.0, 2.0\]; "
                                           r"allowed: a homogeneous rigid transform"):
        load_rig_file(path)


@pytest.mark.parametrize("max_depth, message", [
    ("{rows: 1, cols: 2, data: [5, 7]}", r"max_depth = \[\[5.0, 7.0\]\]; allowed: one number"),
    ("[5, 7]", r"max_depth = \[5.0, 7.0\]; allowed: one number"),
    ("fifty", r"max_depth is not a matrix or a list of numbers"),
])
def test_max_depth_is_one_number(tmp_path, max_depth, message):
    path = tmp_path / "calib.yaml"
    path.write_text(PLAIN_YAML.format(rows=3, data=K_DATA) + f"max_depth: {max_depth}\n")
    with pytest.raises(RigFileError, match=rf"^{path}: {message}"):
        read_calibration(path)


# ---- rounded rotations (issue 36, item 3) ----

def rounded_camchain(path, decimals):
    """A Kalibr camchain whose T_cn_cnm1 is written rounded to `decimals`, as people copy them."""
    R = np.array(ROTATION)
    transform = np.eye(4)
    transform[:3, :3], transform[:3, 3] = R, -R @ TRANSLATION
    return kalibr_camchain(path, T_cn_cnm1=np.round(transform, decimals).tolist())


def test_a_kalibr_chain_with_a_rotation_rounded_to_5_decimals_is_re_orthonormalised_with_a_note(tmp_path):
    path = rounded_camchain(tmp_path / "camchain.yaml", 5)
    rounded = np.round(np.array(ROTATION), 5)
    off = np.abs(rounded @ rounded.T - np.eye(3)).max()
    assert 1e-6 < off < 1e-4  # refused before (a Rig takes 1e-6), within the tolerance now
    calibrated = load_rig_file(path)
    R = calibrated.rig.R
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)
    assert abs(np.linalg.det(R) - 1) < 1e-14 and np.abs(R - rounded).max() < 1e-5
    (note,) = calibrated.notes
    assert note.startswith(f"{path}: cam1: T_cn_cnm1: the rotation is orthonormal to ")
    assert "re-orthonormalised to the nearest rotation" in note
    # the projector still projects where cv2.projectPoints puts points with the file's own R and T
    points = np.array([[0.1, -0.2, 1.0], [-0.4, 0.3, 2.5], [0.5, 0.4, 6.0]])
    transform = np.round(np.hstack([np.array(ROTATION), (-np.array(ROTATION) @ TRANSLATION)[:, None]]), 5)
    expected, _ = cv2.projectPoints(points, cv2.Rodrigues(transform[:, :3])[0], transform[:, 3], K2, None)
    xp, yp, _ = project_to_projector(points, calibrated.rig)
    np.testing.assert_allclose(np.stack([xp, yp], -1), expected.reshape(-1, 2), atol=0.05)
    # through a config, the rig carries the note for generate to print
    config = config_from_dict({"rig": {"file": str(path)}}, "gen.toml")
    assert config.calibrated_rig.notes == (note,)


def test_a_rotation_beyond_the_tolerance_names_the_users_file_and_key(tmp_path):
    path = rounded_camchain(tmp_path / "camchain.yaml", 2)
    refused = rf"{path}: cam1: T_cn_cnm1 is not a rotation"
    with pytest.raises(RigFileError, match=rf"^{refused} \(\|R R\^T - I\| = .*allowed: a proper rotation "
                                           r"\(det \+1\), orthonormal to 0.0001"):
        load_rig_file(path)
    with pytest.raises(ConfigError, match=rf"^gen.toml: \[rig\] file: {refused}"):
        config_from_dict({"rig": {"file": str(path)}}, "gen.toml")
    mirrored = write_storage(tmp_path / "mirror.yaml", R=np.diag([1.0, 1.0, -1.0]))  # det -1: a reflection
    with pytest.raises(RigFileError, match=rf"^{mirrored}: R is not a rotation .*det -1"):
        load_rig_file(mirrored)
    rounded = write_storage(tmp_path / "rounded.yaml", R=np.round(np.array(ROTATION), 5))  # OpenCV's R
    assert load_rig_file(rounded).notes[0].startswith(f"{rounded}: R: the rotation is orthonormal to")


def test_a_rotation_a_rig_takes_is_kept_as_it_is(tmp_path):
    """Files accepted before keep their bytes: no note, the very matrix."""
    calibrated = load_rig_file(kalibr_camchain(tmp_path / "camchain.yaml"))
    assert calibrated.notes == () and calibrated.rig.projector_rotation == ROTATION


# ---- sources and names of a rig put together from parts (issue 36, items 3 and 4) ----

def test_sources_name_each_part_and_explicit_keys(tmp_path):
    path = kalibr_camchain(tmp_path / "camchain.yaml")
    whole = configured_rig(RigConfig(file=str(path), baseline=0.07), "g.toml: [rig]")
    assert dict(whole.sources) == {"camera": str(path), "projector": str(path),
                                   "pose": f"{path}, then g.toml: [rig] baseline, projector_y ... (non-zero)",
                                   "second camera": str(path), "max depth": "g.toml: [rig] max_depth"}
    assert whole.rig.name == "camchain" and whole.notes == ()
    single_camera_sample(tmp_path / "ost.yaml")
    mixed = configured_rig(RigConfig(camera_file=str(tmp_path / "ost.yaml"), projector_file=str(path)), "g")
    assert mixed.rig.name == "ost (camera) + camchain (projector)"
    assert mixed.source("camera") == str(tmp_path / "ost.yaml") and mixed.source("pose") == str(path)
    assert mixed.source("second camera") == "preset structure_core"
    assert "the projector and its pose are those of " + str(path) in mixed.notes[0]
