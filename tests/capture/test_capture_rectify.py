"""Rectification of real frames: a checkerboard seen through a lens with known distortion, imported
with the calibration, lands where the rig's pinhole camera (what the generator renders) puts it.

The distorted frames are drawn independently of the code under test: each distorted pixel's ray
comes from cv2.undistortPointsIter (the iterative inverse of the distortion model), while
rectification uses cv2.initUndistortRectifyMap (the forward model). Corners are found with
cv2.findChessboardCornersSB and compared with the board's analytic pinhole projection.
"""

import cv2
import numpy as np
import pytest

from capture.rectify import Rectifier
from commands.cli import main
from dotsim.dataset import open_dataset, read_scene
from dotsim.rig.files import Lens
from dotsim.rig.geometry import Intrinsics

WIDTH, HEIGHT = 320, 240
LENS_K = np.array([[262.0, 0.0, 161.3], [0.0, 258.0, 118.6], [0.0, 0.0, 1.0]])
LENS_D = np.array([-0.28, 0.09, 0.0015, -0.001, 0.0])
PINHOLE = Intrinsics(WIDTH, HEIGHT, 260.0, 260.0, 161.3, 118.6)  # the square pinhole model: (fx + fy) / 2
SQUARE = 0.12  # board square, in normalised image units (board at z = 1)
INNER = (7, 5)  # inner corners


def board(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Reflectance of a checkerboard (8 x 6 squares, white margin) at normalised coordinates, its
    centre on the optical axis."""
    i = np.floor(x / SQUARE + (INNER[0] + 1) / 2)
    j = np.floor(y / SQUARE + (INNER[1] + 1) / 2)
    inside = (i >= 0) & (i <= INNER[0]) & (j >= 0) & (j <= INNER[1])
    return np.where(inside & ((i + j) % 2 == 1), 0.1, 0.9)


def render(rays, supersample=4) -> np.ndarray:
    """Mean board value over s x s sub-pixel rays; `rays(u, v)` gives normalised (x, y) per pixel position."""
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    v, u = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    total = np.zeros((HEIGHT, WIDTH))
    for du in offsets:
        for dv in offsets:
            x, y = rays(u + du, v + dv)
            total += board(x, y)
    return total / supersample**2


def distorted_rays(u, v):
    points = np.stack([u.ravel(), v.ravel()], -1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    normalised = cv2.undistortPointsIter(points, LENS_K, LENS_D, None, None, criteria).reshape(-1, 2)
    return normalised[:, 0].reshape(u.shape), normalised[:, 1].reshape(u.shape)


def expected_corners() -> np.ndarray:
    """The inner corners as the pinhole camera sees them, row by row."""
    xs = (np.arange(INNER[0]) - (INNER[0] - 1) / 2) * SQUARE
    ys = (np.arange(INNER[1]) - (INNER[1] - 1) / 2) * SQUARE
    x, y = np.meshgrid(xs, ys)
    return np.stack([PINHOLE.fx * x + PINHOLE.cx, PINHOLE.fy * y + PINHOLE.cy], -1).reshape(-1, 2)


def corner_error(image: np.ndarray) -> float:
    """Largest distance (px) between the board's corners found in `image` and where the pinhole puts them."""
    found, corners = cv2.findChessboardCornersSB(np.clip(image * 255, 0, 255).astype(np.uint8), INNER)
    assert found
    corners = corners.reshape(-1, 2)
    expected = expected_corners()
    if np.linalg.norm(corners[0] - expected[0]) > np.linalg.norm(corners[0] - expected[-1]):
        corners = corners[::-1]  # the detector may start from either end
    return float(np.abs(corners - expected).max())


@pytest.fixture(scope="module")
def distorted():
    return render(distorted_rays)


def test_rectifier_puts_the_corners_where_the_pinhole_does(distorted):
    lens = Lens(Intrinsics(WIDTH, HEIGHT, *LENS_K[[0, 1, 0, 1], [0, 1, 2, 2]]), tuple(LENS_D), "radtan")
    rectified = Rectifier(lens, PINHOLE).image(distorted.astype(np.float32))
    assert corner_error(distorted) > 3.0  # the lens moves the outer corners by several pixels
    assert corner_error(rectified) < 0.2
    pinhole = render(lambda u, v: ((u - PINHOLE.cx) / PINHOLE.fx, (v - PINHOLE.cy) / PINHOLE.fy))
    assert corner_error(pinhole) < 0.2  # the detector itself is this accurate (0.15 px)
    inner = np.s_[20:-20, 20:-20]
    assert np.abs(rectified[inner] - pinhole[inner]).mean() < 0.01


def test_capture_import_with_a_calibration_file_rectifies(tmp_path, distorted):
    calibration = tmp_path / "ir.yml"  # OpenCV's calibration sample layout
    storage = cv2.FileStorage(str(calibration), cv2.FILE_STORAGE_WRITE)
    for key, value in (("image_width", WIDTH), ("image_height", HEIGHT), ("camera_matrix", LENS_K),
                       ("distortion_coefficients", LENS_D.reshape(5, 1)), ("avg_reprojection_error", 0.2)):
        storage.write(key, value)
    storage.release()
    (tmp_path / "rig.toml").write_text('[rig]\npreset = "kinect_v1"\ncamera_file = "ir.yml"\n')
    for folder, level in (("on", 1.0), ("off", 0.3)):
        (tmp_path / folder).mkdir()
        frame = np.round(distorted * level * 65535).astype(np.uint16)
        cv2.imwrite(str(tmp_path / folder / "frame_0.png"), frame)
    status = main(["capture", "import", "--on", str(tmp_path / "on"), "--off", str(tmp_path / "off"), "--rig",
                   str(tmp_path / "rig.toml"), "--out", str(tmp_path / "data"), "--frames-per-scene", "1"])
    assert status == 0
    scene = read_scene(open_dataset(tmp_path / "data").scenes[0].path)
    assert scene.meta["rig"]["camera"] == PINHOLE.to_dict()
    assert scene.meta["capture"]["rectified_from"]["distortion"] == LENS_D.tolist()
    assert corner_error(scene.frames[0]["ir"].astype(np.float32)) < 0.2
    assert corner_error(scene.frames[0]["ambient"].astype(np.float32) / 0.3) < 0.2


def test_capture_record_rectifies_ir_and_device_depth(tmp_path, distorted):
    """A software RealSense streams the distorted checkerboard; recording with the lens stores the
    pinhole camera's frames (corners where the pinhole puts them, depth kept)."""
    pytest.importorskip("pyrealsense2")
    from capture.devices.realsense import RealSenseDevice
    from capture.record import record
    from dotsim.rig.files import device_rig
    from tests.capture.realsense_software import DEPTH_UNITS, SoftwareStereoModule

    rig = device_rig("pinhole", PINHOLE, (0.05, 0.0, 0.0))
    on = np.round(distorted * 255).astype(np.uint8)
    pose = (on, (on // 4).astype(np.uint8), np.full(on.shape, 1500, np.uint16))
    lens = Lens(Intrinsics(WIDTH, HEIGHT, *LENS_K[[0, 1, 0, 1], [0, 1, 2, 2]]), tuple(LENS_D), "radtan")
    with SoftwareStereoModule(rig, [pose]) as module:
        device = RealSenseDevice(module.device)
        summary = record(device, rig, tmp_path / "rec", scenes=1, frames_per_scene=1, progress=False,
                         preview=False, lens=lens)
        device.close()
    assert summary["frames"] == 1
    scene = read_scene(open_dataset(tmp_path / "rec").scenes[0].path)
    frame = scene.frames[0]
    assert corner_error(frame["ir"].astype(np.float32)) < 0.2
    depth = frame["device_depth"]
    # barrel distortion: every pinhole pixel's source lies inside the recorded image
    assert np.all(depth == np.float32(1500) * np.float32(DEPTH_UNITS))
    assert scene.meta["capture"]["rectified_from"]["model"] == "radtan"


def ros_camera_info(path):
    """The lens as ROS camera_calibration writes its camera_info (plain YAML, no %YAML:1.0 header)."""
    def matrix(array):
        array = np.atleast_2d(array)
        return (f"\n  rows: {array.shape[0]}\n  cols: {array.shape[1]}\n  data: "
                f"[{', '.join(repr(float(v)) for v in array.ravel())}]")

    path.write_text(f"image_width: {WIDTH}\nimage_height: {HEIGHT}\ncamera_name: ir_camera\n"
                    f"camera_matrix:{matrix(LENS_K)}\ndistortion_model: plumb_bob\n"
                    f"distortion_coefficients:{matrix(LENS_D)}\nrectification_matrix:{matrix(np.eye(3))}\n"
                    f"projection_matrix:{matrix(np.hstack([LENS_K, np.zeros((3, 1))]))}\n")
    return path


@pytest.mark.parametrize("flags", [["--rig", "kinect_v1", "--camera-file", "{ros}"], ["--rig", "{ros}"]])
def test_capture_import_with_a_ros_camera_info_by_flag(tmp_path, distorted, capsys, flags):
    """A ROS camera_info, given by --camera-file (with a preset's projector) or as --rig itself (a camera
    alone: the default preset's projector): the frames are rectified to its pinhole model, the rig is
    named after both, and the command says so."""
    ros = ros_camera_info(tmp_path / "ir.yaml")
    for folder, level in (("on", 1.0), ("off", 0.3)):
        (tmp_path / folder).mkdir()
        frame = np.round(distorted * level * 65535).astype(np.uint16)
        cv2.imwrite(str(tmp_path / folder / "frame_0.png"), frame)
    status = main(["capture", "import", "--on", str(tmp_path / "on"), "--off", str(tmp_path / "off"),
                   *(flag.format(ros=ros) for flag in flags), "--out", str(tmp_path / "data"),
                   "--frames-per-scene", "1"])
    assert status == 0
    projector = "kinect_v1" if "kinect_v1" in flags else "structure_core"
    scene = read_scene(open_dataset(tmp_path / "data").scenes[0].path)
    assert scene.meta["rig"]["camera"] == PINHOLE.to_dict()
    assert scene.meta["rig"]["name"] == f"ir_camera (camera) + {projector} (projector)"
    assert corner_error(scene.frames[0]["ir"].astype(np.float32)) < 0.2
    out, err = capsys.readouterr()
    name = f"ir_camera (camera) + {projector} (projector)"
    assert out.startswith(f"rig {name}: camera 320 x 240 px, f 260.00 px")
    assert f"{ros} calibrates the camera alone: the projector and its pose are those of preset {projector}" \
        in err
