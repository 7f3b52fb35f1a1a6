"""Calibration files as people have them, read into their parts: a camera, a projector, the pose
between them. Pure numpy (plus cv2 for OpenCV FileStorage and PyYAML for plain YAML).

Layouts (docs/GEOMETRY.md "Rig files" lists every key):

- dotsim's rig JSON (Rig.to_dict(), or an object holding it under "rig");
- OpenCV's single-camera calibration sample output and ROS camera_info YAML: camera_matrix,
  distortion_coefficients, image_width, image_height (the IR camera only);
- a cv2.stereoCalibrate result in one file, or the stereo_calib sample's intrinsics.yml (M1, D1, M2,
  D2) with the extrinsics.yml (R, T, ...) written beside it: camera 1 is the IR camera, camera 2 the
  projector;
- a Kalibr camchain YAML: cam0 the IR camera, cam1 the projector (T_cn_cnm1 its pose).

Every key a file holds is read, known and ignored (IGNORED_KEYS, named in the docs), or refused
with a one-line RigFileError naming the file and the key: nothing is dropped silently.

OpenCV writes `!!opencv-matrix` data with integer literals (`data: [600, 0, 319.5, ...]` in a
hand-written file) that cv2 4.11's FileNode.mat() reads as garbage for `dt: d`; matrices are
therefore read from their rows, cols and data entries here, number by number.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dotsim.file_io import DuplicateKeyError, unique_keys

CALIBRATION_SUFFIXES = (".json", ".yaml", ".yml", ".xml")

# Names of each part, the cv2.stereoCalibrate / stereo_calib sample ones first.
CAMERA_MATRIX_KEYS = ("K1", "M1", "cameraMatrix1", "camera_matrix")
PROJECTOR_MATRIX_KEYS = ("K2", "M2", "cameraMatrix2", "projector_matrix")
CAMERA_DISTORTION_KEYS = ("D1", "distCoeffs1", "camera_distortion", "distortion_coefficients")
PROJECTOR_DISTORTION_KEYS = ("D2", "distCoeffs2", "projector_distortion")
CAMERA_SIZE_KEYS = ("image_size", "imageSize", "camera_size")
PROJECTOR_SIZE_KEYS = ("projector_size",)
NAME_KEYS = ("name", "camera_name")

# Keys that calibration tools write and dotsim deliberately does not use (docs/GEOMETRY.md).
IGNORED_KEYS = {
    # OpenCV's calibration samples: how the calibration was made and how well it fits
    "calibration_time", "nframes", "nr_of_frames", "board_width", "board_height", "square_size",
    "marker_size", "aspectRatio", "fix_aspect_ratio", "flags", "avg_reprojection_error",
    "per_view_reprojection_errors", "extrinsic_parameters", "image_points", "grid_points",
    # cv2.stereoCalibrate / stereoRectify: essential and fundamental matrices, rectification of a
    # camera pair (dotsim rectifies the camera alone, to its own pinhole model)
    "E", "F", "R1", "R2", "P1", "P2", "Q", "rms",
    # ROS camera_info: the rectified camera ROS would make (dotsim makes its own, square pinhole)
    "projection_matrix",
    # Kalibr: topic, overlap and IMU entries
    "rostopic", "cam_overlaps", "T_cam_imu", "timeshift_cam_imu",
}
# Distortion models, as each tool names them, -> the rectification that undoes them.
RADTAN = "radtan"  # OpenCV's k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4 [tx ty]]]] (cv2.undistort)
FISHEYE = "fisheye"  # equidistant k1 k2 k3 k4 (cv2.fisheye)
DISTORTION_MODELS = {"plumb_bob": RADTAN, "radtan": RADTAN, "rational_polynomial": RADTAN,
                     "equidistant": FISHEYE, "fisheye": FISHEYE, "none": RADTAN}
COEFFICIENT_COUNTS = {RADTAN: (0, 4, 5, 8, 12, 14), FISHEYE: (4,)}
# The largest |R R^T - I| of a file's rotation that is taken, as the nearest rotation (proper_rotation):
# calibration tools and people round rotations to 4-6 decimals, which leaves them 1e-6 to 1e-5 off.
ROTATION_TOLERANCE = 1e-4
STEREO_CALIB_PAIR = ("intrinsics", "extrinsics")  # the stereo_calib sample's fixed file names


class RigFileError(ValueError):
    """A calibration file that cannot be read or holds a key or value dotsim cannot use; the message
    names the file and the key."""


@dataclass(frozen=True)
class CameraPart:
    """A camera (or projector) as a file gives it: the 3x3 matrix, the image size (None when the file
    has none, as the stereo_calib sample's), distortion coefficients (empty: none) and their model."""

    matrix: np.ndarray
    size: tuple[int, int] | None
    distortion: tuple[float, ...]
    model: str
    where: str  # the file and key, for messages

    @property
    def distorted(self) -> bool:
        return self.model == FISHEYE or any(value != 0 for value in self.distortion)


@dataclass(frozen=True)
class Calibration:
    """What one calibration file (or stereo_calib pair) holds; each part None when it is absent.
    rotation / translation: X_projector = R X_camera + T (OpenCV's stereo convention), metres."""

    path: Path
    camera: CameraPart | None = None
    projector: CameraPart | None = None
    rotation: np.ndarray | None = None
    translation: np.ndarray | None = None
    name: str | None = None
    max_depth: float | None = None
    rig: object | None = None  # a dotsim rig JSON: the dotsim.rig.geometry.Rig itself
    notes: tuple[str, ...] = ()  # what was adjusted on reading (a rounded rotation), one line each


class _Keys:
    """The entries of one mapping of a file; records which were read so the rest can be checked."""

    def __init__(self, tree: dict, where: str):
        self.tree, self.where, self.used = tree, where, set()

    def get(self, names: tuple[str, ...]):
        """(name, value) of the first of `names` present, or (None, None)."""
        for name in names:
            if self.tree.get(name) is not None:
                self.used.add(name)
                return name, self.tree[name]
        return None, None

    def refuse_unknown(self, known=IGNORED_KEYS) -> None:
        for key in self.tree:
            if key not in self.used and key not in known:
                raise RigFileError(f"{self.where}: key {key!r} is neither read nor a known calibration "
                                       "key that dotsim ignores (docs/GEOMETRY.md \"Rig files\" lists both); "
                                       "remove or rename it")


def read_calibration(path: str | Path) -> Calibration:
    """The parts of a calibration file (any layout of the module docstring); RigFileError naming
    the file and the key or value at fault."""
    from dotsim.rig.geometry import Rig

    path = Path(path)
    tree = read_tree(path)
    if path.suffix.lower() == ".json" and ("rig" in tree or "projector_translation" in tree):
        # scene.json, pattern .json and `capture info` files hold more than the rig: only "rig" is read
        try:
            return Calibration(path, rig=Rig.from_dict(tree["rig"] if "rig" in tree else tree))
        except ValueError as error:
            raise RigFileError(f"{path}: {error}") from None
    where = str(path)
    partner = _stereo_calib_partner(path)
    if partner is not None:
        other = read_tree(partner)
        if duplicated := sorted(set(tree) & set(other)):
            raise RigFileError(f"{path} and {partner}: both hold {', '.join(duplicated)}; allowed: "
                                   "stereo_calib's pair (M1, D1, M2, D2 in one; R, T, ... in the other)")
        tree, where = {**tree, **other}, f"{path} (with {partner.name})"
    cams = sorted(key for key in tree if re.fullmatch(r"cam\d+", key))
    calibration = _kalibr(tree, cams, path, where) if cams else _opencv(tree, path, where)
    return calibration


def _stereo_calib_partner(path: Path) -> Path | None:
    """The other file of stereo_calib's intrinsics.yml / extrinsics.yml pair, when it lies beside."""
    if path.stem not in STEREO_CALIB_PAIR:
        return None
    other = STEREO_CALIB_PAIR[1 - STEREO_CALIB_PAIR.index(path.stem)]
    partner = path.with_name(other + path.suffix)
    return partner if partner.is_file() else None


def read_tree(path: Path) -> dict:
    """A calibration file as nested dicts, lists, numbers and strings (a matrix stays a mapping with
    rows, cols and data). JSON by json, YAML with OpenCV's `%YAML:1.0` header and XML by
    cv2.FileStorage, plain YAML (ROS, Kalibr) by PyYAML."""
    suffix = path.suffix.lower()
    if suffix not in CALIBRATION_SUFFIXES:
        raise RigFileError(f"{path}: not a rig file; allowed: {', '.join(CALIBRATION_SUFFIXES)} "
                               "(dotsim rig JSON, OpenCV FileStorage, ROS camera_info or Kalibr YAML)")
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise RigFileError(f"{path}: rig file not found") from None
    except (OSError, UnicodeDecodeError) as error:
        raise RigFileError(f"{path}: cannot read the rig file ({error})") from None
    try:
        if suffix == ".json":
            try:
                tree = json.loads(text, object_pairs_hook=unique_keys)
            except json.JSONDecodeError as error:
                raise RigFileError(f"{path}: not valid JSON ({error})") from None
        elif suffix != ".xml" and not text.lstrip().startswith("%YAML"):
            tree = _plain_yaml_tree(path, text)
        else:
            tree = _file_storage_tree(path, text)
    except DuplicateKeyError as duplicate:
        raise RigFileError(f"{path}: key {duplicate.key!r} is given twice in one mapping; allowed: each key "
                           "once (YAML readers keep the last, OpenCV's the first)") from None
    if not isinstance(tree, dict):
        raise RigFileError(f"{path}: holds a {type(tree).__name__}, not a mapping of calibration keys")
    return tree


def _plain_yaml_tree(path: Path, text: str):
    import yaml

    class UniqueKeys(yaml.SafeLoader):
        """PyYAML's safe loader, refusing a key given twice (it would keep the last silently)."""

    def mapping(loader, node, deep=False):
        loader.flatten_mapping(node)
        return unique_keys((loader.construct_object(key, deep=deep),
                            loader.construct_object(value, deep=deep)) for key, value in node.value)

    UniqueKeys.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, mapping)
    try:
        return yaml.load(text, Loader=UniqueKeys)  # noqa: S506 (a SafeLoader)
    except yaml.YAMLError as error:
        reason = " ".join(str(error).split())
        raise RigFileError(f"{path}: not valid YAML ({reason})") from None


def _file_storage_tree(path: Path, text: str) -> dict:
    import cv2

    try:
        storage = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, SystemError) as error:  # a parse error surfaces as SystemError in cv2 4.x
        reason = str(getattr(error, "__cause__", None) or error).strip().splitlines()[-1]
        raise RigFileError(f"{path}: neither a dotsim rig nor an OpenCV FileStorage file "
                               f"({reason})") from None
    if not storage.isOpened():
        raise RigFileError(f"{path}: neither a dotsim rig nor an OpenCV FileStorage file")
    try:
        return _node_value(storage.root(), path)
    finally:
        storage.release()


def _node_value(node, where):
    """The value of a FileStorage node; RigFileError naming the key of a value OpenCV parsed but
    cannot give back (a 400-digit integer)."""
    import cv2

    if node.isMap():
        def value(key):
            try:
                return _node_value(node.getNode(key), f"{where}: {key}")
            except cv2.error as error:
                reason = str(error).strip().splitlines()[-1]
                raise RigFileError(f"{where}: {key}: OpenCV cannot read its value ({reason})") from None

        return unique_keys((key, value(key)) for key in node.keys())
    if node.isSeq():
        return [_node_value(node.at(k), where) for k in range(node.size())]
    if node.isInt():
        value = node.real()
        return int(value) if math.isfinite(value) else value
    if node.isReal():
        return node.real()
    if node.isString():
        return node.string()
    return None


def _floats(value, where: str):
    """A number, or nested lists of them, as floats; RigFileError for anything else (true and false
    included) and for an integer too large for a float."""
    if isinstance(value, list | tuple):
        return [_floats(item, where) for item in value]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise RigFileError(f"{where} is not a matrix or a list of numbers ({value!r} in it)")
    try:
        return float(value)
    except OverflowError:
        raise RigFileError(f"{where} holds a {len(str(abs(value)))}-digit integer, beyond a 64-bit float; "
                           "allowed: finite numbers") from None


def numbers(value, where: str) -> np.ndarray:
    """The numbers of a matrix ({rows, cols, data}, as OpenCV and ROS write it), a list (of lists) or a
    number, as a float64 array (a matrix keeps its rows x cols shape); RigFileError otherwise."""
    shape = None
    if isinstance(value, dict) and "data" in value:
        shape = (value.get("rows"), value.get("cols"))
        value = value["data"]
    floats = _floats(value, where)
    try:
        array = np.asarray(floats, np.float64)
    except ValueError:  # lists of unequal lengths
        raise RigFileError(f"{where} is not a matrix or a list of numbers") from None
    if array.size == 0:
        raise RigFileError(f"{where} is not a matrix or a list of numbers")
    if not np.all(np.isfinite(array)):
        raise RigFileError(f"{where} holds non-finite values {array.ravel().tolist()}")
    if shape is not None:
        if not all(type(n) is int and n > 0 for n in shape) or shape[0] * shape[1] != array.size:
            raise RigFileError(f"{where}: rows {shape[0]} x cols {shape[1]} does not match its "
                                   f"{array.size} data values")
        array = array.reshape(shape)
    return array


def _matrix(keys: _Keys, names, shape, required=True):
    name, value = keys.get(names)
    if name is None:
        if required:
            raise RigFileError(f"{keys.where}: missing key; allowed names: {' or '.join(names)}")
        return None, None
    values = numbers(value, f"{keys.where}: {name}")
    if values.size != int(np.prod(shape)):
        allowed = f"a {shape[0]} x {shape[1]} matrix" if len(shape) == 2 else f"{shape[0]} numbers"
        raise RigFileError(f"{keys.where}: {name} has {values.size} values; allowed: {allowed}")
    return name, values.reshape(shape)


def _pinhole_matrix(name: str, K: np.ndarray, where: str) -> np.ndarray:
    if K[0, 1] != 0 or K[1, 0] != 0 or K[2].tolist() != [0.0, 0.0, 1.0]:
        raise RigFileError(f"{where}: {name} = {K.tolist()} is not a pinhole matrix "
                               "[[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (zero skew)")
    for axis, value in (("fx", K[0, 0]), ("fy", K[1, 1])):
        if value <= 0:
            raise RigFileError(f"{where}: {name} {axis} = {value:g}; allowed: a positive focal length (px)")
    return K


def _whole_pixels(name: str, values: np.ndarray, where: str) -> tuple[int, int]:
    if values.size != 2:
        raise RigFileError(f"{where}: {name} = {values.ravel().tolist()}; allowed: [width, height] in px")
    width, height = values.ravel()
    if width != int(width) or height != int(height) or width <= 0 or height <= 0:
        raise RigFileError(f"{where}: {name} = {width:g} x {height:g}; allowed: positive whole pixels")
    return int(width), int(height)


def _size(keys: _Keys, names: tuple[str, ...], prefix: str) -> tuple[int, int] | None:
    """(width, height) from a [width, height] entry or <prefix>_width and <prefix>_height; None when
    the file gives neither."""
    name, value = keys.get(names)
    if name is not None:
        return _whole_pixels(name, numbers(value, f"{keys.where}: {name}"), keys.where)
    pair = [keys.get((f"{prefix}_{axis}",))[1] for axis in ("width", "height")]
    if all(value is None for value in pair):
        return None
    if any(value is None for value in pair):
        raise RigFileError(f"{keys.where}: {prefix}_width and {prefix}_height go together; one is missing")
    name = f"{prefix}_width/{prefix}_height"
    return _whole_pixels(name, numbers(pair, f"{keys.where}: {name}"), keys.where)


def _distortion_model(keys: _Keys) -> str:
    """The camera's distortion model: distortion_model (ROS), fisheye_model (OpenCV's sample) or
    OpenCV's rational model by default."""
    name, value = keys.get(("distortion_model",))
    _, fisheye = keys.get(("fisheye_model",))
    if fisheye not in (None, 0, 1, True, False):
        raise RigFileError(f"{keys.where}: fisheye_model = {fisheye!r}; allowed: 0 or 1")
    if name is None:
        return FISHEYE if fisheye else RADTAN
    if value not in DISTORTION_MODELS:
        raise RigFileError(f"{keys.where}: distortion_model = {value!r}; allowed: "
                               f"{', '.join(DISTORTION_MODELS)}")
    return DISTORTION_MODELS[value]


def _coefficients(name: str, value, model: str, where: str) -> tuple[float, ...]:
    coefficients = numbers(value, f"{where}: {name}").ravel()
    if coefficients.size not in COEFFICIENT_COUNTS[model]:
        raise RigFileError(f"{where}: {name} has {coefficients.size} coefficients; allowed for the "
                               f"{model} model: {', '.join(map(str, COEFFICIENT_COUNTS[model]))}")
    return tuple(coefficients.tolist()) if model == FISHEYE or np.any(coefficients) else ()


def _opencv_camera(keys: _Keys, role: str) -> CameraPart | None:
    camera = role == "camera"
    matrix_keys = CAMERA_MATRIX_KEYS if camera else PROJECTOR_MATRIX_KEYS
    distortion_keys = CAMERA_DISTORTION_KEYS if camera else PROJECTOR_DISTORTION_KEYS
    name, K = _matrix(keys, matrix_keys, (3, 3), required=False)
    if name is None:
        size_keys = (*(CAMERA_SIZE_KEYS if camera else PROJECTOR_SIZE_KEYS),
                     *(f"{'image' if camera else 'projector'}_{axis}" for axis in ("width", "height")))
        if stray := [key for key in (*distortion_keys, *size_keys) if key in keys.tree]:
            raise RigFileError(f"{keys.where}: {stray[0]} without a {role} matrix; allowed names of the "
                               f"matrix: {' or '.join(matrix_keys)}")
        return None
    K = _pinhole_matrix(name, K, keys.where)
    model = _distortion_model(keys) if camera else RADTAN
    distortion_name, value = keys.get(distortion_keys)
    distortion = () if value is None else _coefficients(distortion_name, value, model, keys.where)
    if model == FISHEYE and not distortion:
        raise RigFileError(f"{keys.where}: a fisheye camera needs its 4 distortion coefficients "
                               f"({' or '.join(CAMERA_DISTORTION_KEYS)})")
    size = _size(keys, CAMERA_SIZE_KEYS, "image") if camera else _size(keys, PROJECTOR_SIZE_KEYS, "projector")
    return CameraPart(K, size, distortion, model, f"{keys.where}: {name}")


def _opencv(tree: dict, path: Path, where: str) -> Calibration:
    """OpenCV's samples, cv2.stereoCalibrate results, ROS camera_info (all flat key layouts)."""
    keys = _Keys(tree, where)
    camera = _opencv_camera(keys, "camera")
    projector = _opencv_camera(keys, "projector")
    _, rotation = _matrix(keys, ("R",), (3, 3), required=False)
    _, translation = _matrix(keys, ("T",), (3,), required=False)
    rotation, notes = proper_rotation(rotation, f"{where}: R") if rotation is not None else (None, ())
    name_key, value = keys.get(("rectification_matrix",))
    if name_key is not None and not np.allclose(numbers(value, f"{where}: {name_key}").ravel(),
                                                np.eye(3).ravel()):
        raise RigFileError(f"{where}: rectification_matrix is not the identity: the camera_info of one "
                               "camera of a rectified stereo pair; allowed: a monocular calibration "
                               "(identity), dotsim rectifies the camera to its own pinhole model")
    calibration = Calibration(path, camera, projector, rotation, translation, *_name_and_depth(keys),
                              notes=notes)
    keys.refuse_unknown()
    if camera is None and projector is None:
        raise RigFileError(f"{where}: no camera in it; allowed names of the camera matrix: "
                               f"{' or '.join(CAMERA_MATRIX_KEYS)} (or a Kalibr camchain's cam0)")
    return calibration


def proper_rotation(matrix: np.ndarray, where: str) -> tuple[np.ndarray, tuple[str, ...]]:
    """A file's rotation as dotsim takes it, and what was done to it (one line, or nothing): as it is
    when a Rig takes it (dotsim.rig.geometry.is_rotation), else the nearest rotation (the SVD's U V^T)
    when R R^T differs from the identity by at most ROTATION_TOLERANCE (rounded values) and det R > 0.
    RigFileError naming `where` (the file and key) otherwise."""
    from dotsim.rig.geometry import is_rotation

    if is_rotation(matrix):
        return matrix, ()
    off = float(np.abs(matrix @ matrix.T - np.eye(3)).max())
    det = float(np.linalg.det(matrix))
    if det <= 0 or off > ROTATION_TOLERANCE:
        raise RigFileError(f"{where} is not a rotation (|R R^T - I| = {off:.2g}, det {det:.6g}); allowed: a "
                           f"proper rotation (det +1), orthonormal to {ROTATION_TOLERANCE:g} (rounded values "
                           "are re-orthonormalised)")
    u, _, vt = np.linalg.svd(matrix)
    nearest = u @ vt
    return nearest, (f"{where}: the rotation is orthonormal to {off:.1e} only (rounded); re-orthonormalised "
                     f"to the nearest rotation, which differs from it by at most "
                     f"{float(np.abs(nearest - matrix).max()):.1e} (allowed: |R R^T - I| up to "
                     f"{ROTATION_TOLERANCE:g})",)


def _name_and_depth(keys: _Keys) -> tuple[str | None, float | None]:
    name_key, name = keys.get(NAME_KEYS)
    if name_key is not None and not isinstance(name, str):
        raise RigFileError(f"{keys.where}: {name_key} = {name!r}; allowed: a string")
    depth_key, depth = keys.get(("max_depth",))
    if depth_key is not None:
        values = numbers(depth, f"{keys.where}: max_depth")
        if values.size != 1:
            raise RigFileError(f"{keys.where}: max_depth = {values.tolist()}; allowed: one number (metres)")
        depth = float(values.ravel()[0])
    return name or None, depth


KALIBR_KEYS = ("camera_model", "intrinsics", "distortion_model", "distortion_coeffs", "resolution",
               "T_cn_cnm1")


def _kalibr_camera(tree: dict, cam: str, where: str) -> tuple[CameraPart, np.ndarray | None]:
    """One camera of a camchain and its T_cn_cnm1 (4 x 4, X_this = T X_previous) when it has one."""
    if not isinstance(tree, dict):
        raise RigFileError(f"{where}: {cam} is not a mapping of camera keys")
    keys = _Keys(tree, f"{where}: {cam}")
    _, model = keys.get(("camera_model",))
    if model != "pinhole":
        raise RigFileError(f"{keys.where}: camera_model = {model!r}; allowed: pinhole (dotsim's cameras "
                               "are pinholes with lens distortion)")
    _, intrinsics = _matrix(keys, ("intrinsics",), (4,))
    fu, fv, pu, pv = intrinsics
    K = _pinhole_matrix("intrinsics", np.array([[fu, 0, pu], [0, fv, pv], [0, 0, 1.0]]), keys.where)
    _, resolution = keys.get(("resolution",))
    if resolution is None:
        raise RigFileError(f"{keys.where}: missing key; allowed names: resolution")
    size = _whole_pixels("resolution", numbers(resolution, f"{keys.where}: resolution"), keys.where)
    distortion_model = _distortion_model(keys)
    name, value = keys.get(("distortion_coeffs",))
    distortion = () if value is None else _coefficients(name, value, distortion_model, keys.where)
    _, transform = _matrix(keys, ("T_cn_cnm1",), (4, 4), required=False)
    keys.refuse_unknown()
    return CameraPart(K, size, distortion, distortion_model, f"{keys.where}: intrinsics"), transform


def _kalibr(tree: dict, cams: list[str], path: Path, where: str) -> Calibration:
    """A Kalibr camchain: cam0 the IR camera, cam1 (optional) the projector."""
    keys = _Keys(tree, where)
    if cams[0] != "cam0" or cams[1:] not in ([], ["cam1"]):
        raise RigFileError(f"{where}: cameras {', '.join(cams)}; allowed: cam0 (the IR camera) and "
                               "optionally cam1 (the projector)")
    camera, _ = _kalibr_camera(keys.get(("cam0",))[1], "cam0", where)
    projector = rotation = translation = None
    notes = ()
    if "cam1" in cams:
        projector, transform = _kalibr_camera(keys.get(("cam1",))[1], "cam1", where)
        if transform is None:
            raise RigFileError(f"{where}: cam1 has no T_cn_cnm1 (its pose from cam0)")
        if transform[3].tolist() != [0.0, 0.0, 0.0, 1.0]:
            raise RigFileError(f"{where}: cam1: T_cn_cnm1 bottom row {transform[3].tolist()}; allowed: a "
                               "homogeneous rigid transform, bottom row [0, 0, 0, 1]")
        rotation, notes = proper_rotation(transform[:3, :3], f"{where}: cam1: T_cn_cnm1")
        translation = transform[:3, 3]
    calibration = Calibration(path, camera, projector, rotation, translation, *_name_and_depth(keys),
                              notes=notes)
    keys.refuse_unknown()
    return calibration
