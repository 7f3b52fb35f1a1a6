"""Rigs from files, and the checks a rig from outside must pass before anything renders with it.

Three layouts are read (docs/GEOMETRY.md "Rig files" has examples):

- dotsim's rig JSON: Rig.to_dict() itself, or any JSON object holding it under "rig" (scene.json,
  the presets in dotsim/rigs/, the file `dotsim capture info` writes, a pattern's .json);
- an OpenCV FileStorage file (YAML, JSON or XML, read with cv2.FileStorage) in the layout of a
  cv2.stereoCalibrate result with the IR camera as camera 1 and the projector as camera 2: K1, K2
  (or camera_matrix / projector_matrix), R and T (X_projector = R X_camera + T), the image sizes,
  and optionally D1 / D2, name and max_depth.

Images are rectified in dotsim (pinhole, no lens distortion): a non-zero distortion coefficient is
refused rather than ignored.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from dotsim.rig import Intrinsics, Rig, check_square_pixels, get_preset, project_to_projector, rotation_matrix

RIG_FILE_SUFFIXES = (".json", ".yaml", ".yml", ".xml")

# Accepted FileStorage names, first the cv2.stereoCalibrate / stereo_calib sample ones.
CAMERA_MATRIX_KEYS = ("K1", "M1", "cameraMatrix1", "camera_matrix")
PROJECTOR_MATRIX_KEYS = ("K2", "M2", "cameraMatrix2", "projector_matrix")
CAMERA_DISTORTION_KEYS = ("D1", "distCoeffs1", "camera_distortion")
PROJECTOR_DISTORTION_KEYS = ("D2", "distCoeffs2", "projector_distortion")
CAMERA_SIZE_KEYS = ("image_size", "imageSize", "camera_size")
PROJECTOR_SIZE_KEYS = ("projector_size",)

# Depths (m) at which a projector must light part of the camera's view: from a near surface to
# the rig's max_depth.
_COVERAGE_NEAR = 0.3
_COVERAGE_GRID = 17


class RigFileError(ValueError):
    """A rig file that cannot be read or describes an unusable rig; the message names the file."""


def load_rig_file(path: str | os.PathLike) -> Rig:
    """The rig described by a file (dotsim rig JSON or OpenCV FileStorage), checked by check_rig.

    Raises RigFileError naming the file and the key or value at fault.
    """
    path = Path(path)
    if path.suffix.lower() not in RIG_FILE_SUFFIXES:
        raise RigFileError(f"{path}: not a rig file; allowed: {', '.join(RIG_FILE_SUFFIXES)} "
                           "(dotsim rig JSON or OpenCV FileStorage)")
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise RigFileError(f"{path}: rig file not found") from None
    except (OSError, UnicodeDecodeError) as error:
        raise RigFileError(f"{path}: cannot read the rig file ({error})") from None
    data = None
    if path.suffix.lower() == ".json":
        try:
            data = json.loads(text)
        except ValueError as error:
            raise RigFileError(f"{path}: not valid JSON ({error})") from None
    if isinstance(data, dict) and ("rig" in data or "projector_translation" in data):
        try:
            rig = Rig.from_dict(data["rig"] if "rig" in data else data)
        except ValueError as error:
            raise RigFileError(f"{path}: {error}") from None
    else:
        rig = _rig_from_opencv(path)
    check_rig(rig, str(path))
    return rig


def configured_rig(settings, where: str) -> Rig:
    """The rig of the generator's [rig] settings (generator.config.RigConfig; docs/CONFIG.md): the
    preset or `file`, then explicit camera / projector intrinsics, projector offsets and rotation,
    max_depth; checked (check_rig, and square camera pixels, which the renderer needs), then scaled.

    Zero means "keep": a non-zero offset replaces the base rig's, non-zero angles replace its
    rotation. Raises RigFileError naming `where` and the key.
    """
    try:
        base = load_rig_file(settings.file) if settings.file else get_preset(settings.preset)
    except RigFileError as error:
        raise RigFileError(f"{where} file: {error}") from None
    translation = [value if value != 0.0 else kept for value, kept in
                   zip((settings.baseline, settings.projector_y, settings.projector_z),
                       base.projector_translation, strict=True)]
    angles = (settings.projector_rotation_x, settings.projector_rotation_y, settings.projector_rotation_z)
    rotation = rotation_matrix(*np.radians(angles)) if any(angles) else base.projector_rotation
    try:
        rig = replace(base, camera=_explicit_intrinsics(settings, "camera", base.camera, where),
                      projector=_explicit_intrinsics(settings, "projector", base.projector, where),
                      projector_translation=tuple(translation), projector_rotation=rotation,
                      max_depth=settings.max_depth)
    except ValueError as error:
        raise RigFileError(f"{where}: {error}") from None
    check_rig(rig, where)
    try:
        check_square_pixels(rig.camera.fx, rig.camera.fy)
    except ValueError as error:
        raise RigFileError(f"{where}: {error}") from None
    return rig.scaled(settings.scale) if settings.scale != 1.0 else rig


def _explicit_intrinsics(settings, role: str, kept: Intrinsics, where: str) -> Intrinsics:
    """<role>_width ... <role>_cy of the settings as Intrinsics, or `kept` when all are 0."""
    keys = ("width", "height", "fx", "fy", "cx", "cy")
    values = {key: getattr(settings, f"{role}_{key}") for key in keys}
    if not any(values.values()):
        return kept
    if missing := [f"{role}_{key}" for key in ("width", "height", "fx") if not values[key]]:
        raise RigFileError(f"{where}: an explicit {role} needs {', '.join(missing)} as well (set "
                           f"{role}_width, {role}_height and {role}_fx, or none of the {role}_* keys)")
    if not values["fy"]:
        values["fy"] = values["fx"]
    if not values["cx"] and not values["cy"]:
        values["cx"], values["cy"] = values["width"] / 2 - 0.5, values["height"] / 2 - 0.5
    return Intrinsics(**values)


def device_rig(name: str, camera: Intrinsics, projector_translation, second_camera_translation=None,
               max_depth: float = 20.0) -> Rig:
    """The rig of a sensor that reports its IR camera but not its projector's optics (RealSense,
    OpenNI2): the projector is drawn as the presets' are (2 projector px per camera px, a field 25%
    wider than the camera's, centred) at `projector_translation` (m, camera frame), unrotated.
    """
    projector = Intrinsics.centred(2 * round(1.25 * camera.width), 2 * round(1.25 * camera.height),
                                   2 * camera.fx)
    return Rig(name=name, camera=camera, projector=projector, projector_translation=projector_translation,
               second_camera_translation=second_camera_translation, max_depth=max_depth)


def rig_file_json(rig: Rig, **extra) -> bytes:
    """The bytes of a dotsim rig file: {"rig": Rig.to_dict(), **extra} (e.g. device, notes)."""
    return (json.dumps({"rig": rig.to_dict(), **extra}, indent=2) + "\n").encode()


def check_rig(rig: Rig, where: str) -> None:
    """Refuse a rig dotsim cannot simulate or use, naming `where` (a file or config key) and the value.

    Checks: principal points inside their images; the projector facing the scene the camera sees
    (not behind the camera); and some camera pixel lit by the projector at some depth from 0.3 m to
    max_depth. Focal lengths are already positive (Intrinsics refuses others).
    """
    for role, intrinsics in (("camera", rig.camera), ("projector", rig.projector)):
        for axis, value, size in (("cx", intrinsics.cx, intrinsics.width),
                                  ("cy", intrinsics.cy, intrinsics.height)):
            if not -0.5 <= value <= size - 0.5:
                raise RigFileError(f"{where}: {role} {axis} = {value:g} is outside the image; allowed: "
                                   f"-0.5 <= {axis} <= {size - 0.5:g} ({role} is {intrinsics.width} x "
                                   f"{intrinsics.height} px)")
    axis = rig.R.T @ np.array([0.0, 0.0, 1.0])  # the projector's optical axis in the camera frame
    if axis[2] <= 0:
        raise RigFileError(f"{where}: the projector points behind the camera (its optical axis in the "
                           f"camera frame is {np.round(axis, 4).tolist()}); allowed: a projector facing "
                           f"the scene (positive z), check R / projector_rotation")
    if rig.projector_translation[2] < -_COVERAGE_NEAR:
        raise RigFileError(f"{where}: the projector sits {-rig.projector_translation[2]:g} m behind the "
                           f"camera (translation {list(rig.projector_translation)}); allowed: z >= "
                           f"{-_COVERAGE_NEAR:g} m")
    if lit_share(rig) == 0.0:
        raise RigFileError(f"{where}: the projector's field misses the camera's view (no camera pixel is "
                           f"lit at any depth from {_COVERAGE_NEAR:g} to {rig.max_depth:g} m); check the "
                           f"projector's pose (translation {list(rig.projector_translation)}) and intrinsics")


def lit_share(rig: Rig) -> float:
    """Largest share of a grid of camera pixels that the projector lights, over depths from 0.3 m to
    max_depth (geometric steps): 0 means the projector can never put a dot in the camera's view."""
    u = np.linspace(-0.5, rig.camera.width - 0.5, _COVERAGE_GRID)
    v = np.linspace(-0.5, rig.camera.height - 0.5, _COVERAGE_GRID)
    uu, vv = np.meshgrid(u, v)
    rays = np.stack([(uu - rig.camera.cx) / rig.camera.fx, (vv - rig.camera.cy) / rig.camera.fy,
                     np.ones_like(uu)], axis=-1)
    best = 0.0
    for depth in np.geomspace(_COVERAGE_NEAR, max(rig.max_depth, _COVERAGE_NEAR), 8):
        xp, yp, _ = project_to_projector(rays * depth, rig)
        inside = ((xp >= -0.5) & (xp <= rig.projector.width - 0.5)
                  & (yp >= -0.5) & (yp <= rig.projector.height - 0.5))
        best = max(best, float(inside.mean()))
    return best


def _rig_from_opencv(path: Path) -> Rig:
    """A rig from an OpenCV FileStorage calibration (names in the module docstring)."""
    import cv2

    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as error:  # a parse error surfaces as SystemError in cv2 4.x
        reason = str(getattr(error, "__cause__", None) or error).strip().splitlines()[-1]
        raise RigFileError(f"{path}: neither a dotsim rig nor an OpenCV FileStorage file "
                           f"({reason})") from None
    if not storage.isOpened():
        raise RigFileError(f"{path}: neither a dotsim rig nor an OpenCV FileStorage file")
    try:
        return _rig_from_storage(storage, path)
    finally:
        storage.release()


def _node(storage, names: tuple[str, ...], path: Path, required: bool = True):
    for name in names:
        node = storage.getNode(name)
        if not node.empty() and not node.isNone():
            return name, node
    if required:
        raise RigFileError(f"{path}: missing key; allowed names: {' or '.join(names)}")
    return None, None


def _numbers(node, name: str, path: Path) -> np.ndarray:
    """The numbers of a FileStorage matrix, sequence or scalar node, as a flat float array."""
    if node.isSeq():
        values = [node.at(k).real() for k in range(node.size())]
    elif node.isReal() or node.isInt():
        values = [node.real()]
    else:
        matrix = node.mat()
        if matrix is None:
            raise RigFileError(f"{path}: {name} is not a matrix or a list of numbers")
        values = matrix.ravel().tolist()
    values = np.asarray(values, np.float64)
    if not np.all(np.isfinite(values)):
        raise RigFileError(f"{path}: {name} holds non-finite values {values.tolist()}")
    return values


def _matrix(storage, names, shape, path: Path) -> tuple[str, np.ndarray]:
    name, node = _node(storage, names, path)
    values = _numbers(node, name, path)
    if values.size != math.prod(shape):
        allowed = f"a {shape[0]} x {shape[1]} matrix" if len(shape) == 2 else f"{shape[0]} numbers"
        raise RigFileError(f"{path}: {name} has {values.size} values; allowed: {allowed}")
    return name, values.reshape(shape)


def _size(storage, names: tuple[str, ...], prefix: str, path: Path) -> tuple[int, int]:
    """(width, height) from a [width, height] entry or from <prefix>_width and <prefix>_height."""
    name, node = _node(storage, names, path, required=False)
    if node is not None:
        values = _numbers(node, name, path)
        if values.size != 2:
            raise RigFileError(f"{path}: {name} = {values.tolist()}; allowed: [width, height] in px")
        width, height = values
    else:
        pair = [storage.getNode(f"{prefix}_{axis}") for axis in ("width", "height")]
        if any(node.empty() or node.isNone() for node in pair):
            raise RigFileError(f"{path}: missing the {prefix} image size; allowed names: "
                               f"{' or '.join(names)} ([width, height]), or {prefix}_width and "
                               f"{prefix}_height")
        name = f"{prefix}_width/{prefix}_height"
        width, height = (_numbers(node, name, path)[0] for node in pair)
    if width != int(width) or height != int(height) or width <= 0 or height <= 0:
        raise RigFileError(f"{path}: {name} = {width:g} x {height:g}; allowed: positive whole pixels")
    return int(width), int(height)


def _intrinsics(storage, matrix_keys, distortion_keys, size_keys, prefix, path: Path) -> Intrinsics:
    name, K = _matrix(storage, matrix_keys, (3, 3), path)
    if K[0, 1] != 0 or K[1, 0] != 0 or K[2].tolist() != [0.0, 0.0, 1.0]:
        raise RigFileError(f"{path}: {name} = {K.tolist()} is not a pinhole matrix "
                           "[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]")
    for axis, value in (("fx", K[0, 0]), ("fy", K[1, 1])):
        if value <= 0:
            raise RigFileError(f"{path}: {name} {axis} = {value:g}; allowed: a positive focal length (px)")
    distortion_name, distortion = _node(storage, distortion_keys, path, required=False)
    if distortion is not None:
        coefficients = _numbers(distortion, distortion_name, path)
        if np.any(coefficients != 0):
            raise RigFileError(f"{path}: {distortion_name} = {coefficients.tolist()} is not zero; dotsim "
                               "needs rectified images: rectify them (cv2.stereoRectify) and give the "
                               "rectified matrices with zero distortion")
    width, height = _size(storage, size_keys, prefix, path)
    return Intrinsics(width, height, float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]))


def _rig_from_storage(storage, path: Path) -> Rig:
    camera = _intrinsics(storage, CAMERA_MATRIX_KEYS, CAMERA_DISTORTION_KEYS, CAMERA_SIZE_KEYS, "image", path)
    projector = _intrinsics(storage, PROJECTOR_MATRIX_KEYS, PROJECTOR_DISTORTION_KEYS, PROJECTOR_SIZE_KEYS,
                            "projector", path)
    _, rotation = _matrix(storage, ("R",), (3, 3), path)
    _, translation = _matrix(storage, ("T",), (3,), path)
    name_node = storage.getNode("name")
    name = name_node.string() if name_node.isString() and name_node.string() else path.stem
    _, max_depth_node = _node(storage, ("max_depth",), path, required=False)
    extra = {} if max_depth_node is None else {"max_depth": _numbers(max_depth_node, "max_depth", path)[0]}
    try:
        # stereoCalibrate: X_projector = R X_camera + T; dotsim: X_projector = R (X_camera - t).
        return Rig(name=name, camera=camera, projector=projector,
                   projector_translation=tuple((-rotation.T @ translation).tolist()),
                   projector_rotation=tuple(tuple(row) for row in rotation.tolist()), **extra)
    except ValueError as error:
        raise RigFileError(f"{path}: {error}") from None
