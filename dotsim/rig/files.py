"""Rigs from files and config keys, and the checks a rig from outside must pass before anything
renders with it.

A rig file is any calibration layout dotsim.rig.calibration_formats reads (dotsim rig JSON, OpenCV's
calibration samples and cv2.stereoCalibrate results, ROS camera_info, Kalibr camchains). The rig
is always a pinhole rig (what Blender renders). A calibrated camera that is not that pinhole (lens
distortion, or fx != fy) becomes a Lens beside the rig: the rig's camera is its square pinhole
model (f = (fx + fy) / 2, the same principal point and size), and real frames are rectified from the
lens to it (capture.rectify), so recordings and renders share one geometry.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from dotsim.rig.calibration_formats import (
    CALIBRATION_SUFFIXES,
    CAMERA_MATRIX_KEYS,
    FISHEYE,
    PROJECTOR_MATRIX_KEYS,
    CameraPart,
    RigFileError,
    read_calibration,
)
from dotsim.rig.geometry import (
    DEFAULT_MAX_DEPTH,
    Intrinsics,
    Rig,
    check_square_pixels,
    project_to_projector,
    rotation_matrix,
)
from dotsim.rig.presets import DEFAULT_PRESET, PRESETS, get_preset

RIG_FILE_SUFFIXES = CALIBRATION_SUFFIXES
PINHOLE = "pinhole"  # a dotsim rig's own camera: taken as it is

# Depths (m) at which a projector must light part of the camera's view: from a near surface to
# the rig's max_depth.
_COVERAGE_NEAR = 0.3
_COVERAGE_GRID = 17
# The [rig] keys <role>_<key> that give a camera or projector explicitly, in Intrinsics' order.
_INTRINSICS_KEYS = ("width", "height", "fx", "fy", "cx", "cy")


@dataclass(frozen=True)
class Lens:
    """The IR camera as calibrated, where it differs from the rig's pinhole camera: its intrinsics
    (fx and fy may differ), distortion coefficients in OpenCV's order and their model ("radtan":
    cv2.undistort's k1 k2 p1 p2 [k3 ...], "fisheye": cv2.fisheye's k1 k2 k3 k4)."""

    intrinsics: Intrinsics
    distortion: tuple[float, ...]
    model: str

    def scaled(self, factor: float) -> Lens:
        """The lens of frames recorded at `factor` times the resolution (coefficients act on
        normalised coordinates and stay)."""
        return replace(self, intrinsics=self.intrinsics.scaled(factor))

    def to_dict(self) -> dict:
        return {"intrinsics": self.intrinsics.to_dict(), "distortion": list(self.distortion),
                "model": self.model}


# The parts of a rig whose sources CalibratedRig records (`dotsim rig show` names them), in its order.
RIG_PARTS = ("camera", "projector", "pose", "second camera", "max depth")


@dataclass(frozen=True)
class CalibratedRig:
    """A rig, the lens real frames are rectified from (None: frames are the rig camera's pinhole
    images already), where each of its RIG_PARTS came from (part -> a preset, a file, a config key) and
    what reading it noted (one line each: a rounded rotation re-orthonormalised, a camera-only
    calibration completed by another rig's projector), for the commands to say."""

    rig: Rig
    lens: Lens | None = None
    sources: tuple[tuple[str, str], ...] = ()
    notes: tuple[str, ...] = ()

    def scaled(self, factor: float) -> CalibratedRig:
        return replace(self, rig=self.rig.scaled(factor), lens=self.lens and self.lens.scaled(factor))

    def source(self, part: str) -> str:
        """Where part `part` (of RIG_PARTS) came from; "" when unknown."""
        return dict(self.sources).get(part, "")

    def rectification_note(self, where: str) -> str | None:
        """The one line generation prints for a calibrated lens, or None."""
        if self.lens is None:
            return None
        what = "lens distortion" if self.lens.distortion or self.lens.model == FISHEYE else "fx != fy"
        camera = self.rig.camera
        return (f"{where}: the calibrated camera has {what}; rendering its pinhole model ({camera.width} x "
                f"{camera.height} px, f {camera.fx:.2f}, principal point ({camera.cx:.2f}, "
                f"{camera.cy:.2f})); "
                "real frames are rectified to it by `dotsim capture import / record` with the same rig")


@dataclass(frozen=True)
class _Parts:
    """A rig being put together from a preset, files and config keys."""

    camera: CameraPart
    projector: CameraPart
    rotation: np.ndarray  # dotsim's pose: X_projector = R (X_camera - t)
    translation: np.ndarray  # t, the projector centre in the camera frame
    names: tuple[str, str]  # whose camera, whose projector (rig_name)
    max_depth: float
    second_camera_translation: tuple | None = None
    sources: tuple[tuple[str, str], ...] = ()  # RIG_PARTS -> where from
    notes: tuple[str, ...] = ()


def rig_name(camera: str, projector: str) -> str:
    """The name of a rig whose camera is `camera`'s and projector `projector`'s: one name when they are
    one rig's, else both, so that a rig put together from a calibration and a preset says so.

    >>> rig_name("structure_core", "structure_core"), rig_name("ir_camera", "structure_core")
    ('structure_core', 'ir_camera (camera) + structure_core (projector)')
    """
    return camera if camera == projector else f"{camera} (camera) + {projector} (projector)"


def _rig_parts(rig: Rig, where: str) -> _Parts:
    """A dotsim rig's parts, taken as they are (its camera is its own pinhole model, never a lens);
    `where` names it (a preset, a file) as every part's source."""
    def part(intrinsics: Intrinsics) -> CameraPart:
        return CameraPart(intrinsics.K, (intrinsics.width, intrinsics.height), (), PINHOLE, where)

    return _Parts(part(rig.camera), part(rig.projector), rig.R, rig.t, (rig.name, rig.name), rig.max_depth,
                  rig.second_camera_translation, tuple((name, where) for name in RIG_PARTS))


def _preset_parts(name: str) -> _Parts:
    return _rig_parts(get_preset(name), f"preset {name}")


def _file_parts(path, roles: tuple[str, ...], base: _Parts | None) -> _Parts:
    """`base` with the parts of `roles` ("camera", "projector": the projector and its pose) taken
    from the rig file at `path`, each required there; without base every part is required."""
    path = Path(path)
    calibration = read_calibration(path)
    if calibration.rig is not None:
        parts = _rig_parts(calibration.rig, str(path))
    else:
        missing = [what for what, value, role in (
            (f"camera matrix ({' or '.join(CAMERA_MATRIX_KEYS)}, or a camchain's cam0)", calibration.camera,
             "camera"),
            (f"projector matrix ({' or '.join(PROJECTOR_MATRIX_KEYS)}, or a camchain's cam1)",
             calibration.projector, "projector"),
            ("rotation (R)", calibration.rotation, "projector"),
            ("translation (T)", calibration.translation, "projector")) if value is None and role in roles]
        if missing:
            raise RigFileError(f"{path}: missing the {', the '.join(missing)}: a {' and '.join(roles)} "
                               "file needs them (docs/GEOMETRY.md \"Rig files\")")
        rotation = calibration.rotation
        # OpenCV: X_projector = R X_camera + T, so the projector centre is t = -R^T T
        translation = None if rotation is None else -rotation.T @ calibration.translation
        name = calibration.name or path.stem
        depth = (str(path) if calibration.max_depth is not None
                 else f"{path} (it gives none: the default, {DEFAULT_MAX_DEPTH:g} m)")
        parts = _Parts(calibration.camera, calibration.projector, rotation, translation, (name, name),
                       calibration.max_depth if calibration.max_depth is not None else DEFAULT_MAX_DEPTH,
                       sources=(*((part, str(path)) for part in RIG_PARTS[:4]), ("max depth", depth)),
                       notes=calibration.notes)
        if calibration.projector is not None and calibration.projector.distorted:
            raise RigFileError(f"{calibration.projector.where}: projector distortion "
                               f"{list(calibration.projector.distortion)} is not zero; dotsim's projector is "
                               "a pinhole whose image is the pattern: give zero coefficients (a pattern "
                               "from `dotsim capture pattern` through this rig already holds the "
                               "projector's distortion)")
    if base is None:
        return parts
    taken = {"camera": {"camera": parts.camera},
             "projector": {"projector": parts.projector, "rotation": parts.rotation,
                           "translation": parts.translation}}
    names = (parts.names[0] if "camera" in roles else base.names[0],
             parts.names[1] if "projector" in roles else base.names[1])
    from_file = {"camera"} if roles == ("camera",) else {"projector", "pose"}
    sources = tuple((part, str(path) if part in from_file else where) for part, where in base.sources)
    return replace(base, names=names, sources=sources, notes=base.notes + parts.notes,
                   **{key: value for role in roles for key, value in taken[role].items()})


def _composed(base: _Parts, camera_file: str = "", projector_file: str = "") -> _Parts:
    """`base` with the camera of `camera_file` and the projector and pose of `projector_file` (either
    may be ""); a camera file completed by another rig's projector says so in a note. RigFileError
    naming the key (camera_file, projector_file) and the file."""
    parts = base
    for key, path, roles in (("camera_file", camera_file, ("camera",)),
                             ("projector_file", projector_file, ("projector",))):
        if path:
            try:
                parts = _file_parts(path, roles, parts)
            except RigFileError as error:
                raise RigFileError(f"{key}: {error}") from None
    if camera_file:
        projector = dict(parts.sources)["projector"]
        parts = replace(parts, notes=parts.notes + (
            f"{camera_file} calibrates the camera alone: the projector and its pose are those of {projector} "
            f"(rig {rig_name(*parts.names)!r})",))
    return parts


def _calibrated(parts: _Parts, where: str, sizes=(None, None)) -> CalibratedRig:
    camera, lens = _camera(parts.camera, sizes[0], "camera")
    projector, _ = _camera(parts.projector, sizes[1], "projector")
    try:
        # OpenCV: X_projector = R X_camera + T; dotsim: X_projector = R (X_camera - t)
        rig = Rig(name=rig_name(*parts.names), camera=camera, projector=projector,
                  projector_translation=tuple(parts.translation.tolist()),
                  projector_rotation=tuple(tuple(row) for row in parts.rotation.tolist()),
                  second_camera_translation=parts.second_camera_translation, max_depth=parts.max_depth)
    except ValueError as error:
        raise RigFileError(f"{where}: {error}") from None
    return CalibratedRig(rig, lens, parts.sources, parts.notes)


def _camera(part: CameraPart, size: tuple[int, int] | None, role: str) -> tuple[Intrinsics, Lens | None]:
    """The pinhole intrinsics of a part and, for a camera that is not that pinhole, its Lens (a
    projector is taken as it is: its distortion is refused when read, and it may have fx != fy)."""
    if part.size and size and part.size != size:
        raise RigFileError(f"{part.where}: the file gives a {part.size[0]} x {part.size[1]} px {role}, "
                           f"[rig] {role}_width / {role}_height {size[0]} x {size[1]}; allowed: leave them "
                           f"out (they give a size the file lacks), or add {role}_fx (an explicit {role})")
    size = part.size or size
    if size is None:
        key = "image_size" if role == "camera" else "projector_size"
        raise RigFileError(f"{part.where}: the file gives no {role} image size (stereo_calib's "
                           f"intrinsics.yml has none); allowed: add {key}: [width, height] to the file, or "
                           f"set [rig] {role}_width and {role}_height")
    K = part.matrix
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    calibrated = Intrinsics(size[0], size[1], fx, fy, cx, cy)
    if part.model == PINHOLE or role == "projector" or (not part.distorted and fx == fy):
        return calibrated, None
    focal = (fx + fy) / 2
    return Intrinsics(size[0], size[1], focal, focal, cx, cy), Lens(calibrated, part.distortion, part.model)


def load_rig_file(path) -> CalibratedRig:
    """The whole rig a file describes (camera, projector and pose; any layout of
    dotsim.rig.calibration_formats), checked by check_rig. Raises RigFileError naming the file and key."""
    calibrated = _calibrated(_file_parts(path, ("camera", "projector"), None), str(path))
    check_rig(calibrated.rig, str(path))
    return calibrated


def holds_camera_only(path) -> bool:
    """Whether the rig file at `path` calibrates a camera and no projector (OpenCV's calibration sample,
    ROS camera_info, a Kalibr chain of cam0 alone). RigFileError naming the file when it is unreadable."""
    calibration = read_calibration(path)
    return calibration.rig is None and calibration.projector is None and calibration.rotation is None


def rig_max_depth(base: str) -> float:
    """The max_depth a preset or rig file gives itself (DEFAULT_MAX_DEPTH for a file that gives none):
    a generator config's [rig] max_depth when it leaves the key out. RigFileError naming the file."""
    parts = _preset_parts(base) if base in PRESETS else _file_parts(base, ("camera", "projector"), None)
    return parts.max_depth


def composed_rig(base: str | Rig = DEFAULT_PRESET, camera_file: str = "", projector_file: str = "",
                 base_name: str = "") -> CalibratedRig:
    """A rig as it is, not through a config's [rig]: `base` (a preset's name, a rig file's path, or a
    Rig as a device reports it, named `base_name` as a source) with the camera of `camera_file` and
    the projector and pose of `projector_file`, the base's own max_depth; checked (check_rig). Raises
    RigFileError naming the file and the key."""
    if isinstance(base, Rig):
        base_name = base_name or f"rig {base.name}"
        parts = _rig_parts(base, base_name)
    else:
        parts = _preset_parts(base) if base in PRESETS else _file_parts(base, ("camera", "projector"), None)
    where = camera_file or projector_file or base_name or str(base)
    calibrated = _calibrated(_composed(parts, camera_file, projector_file), where)
    check_rig(calibrated.rig, where)
    return calibrated


def configured_rig(settings, where: str) -> CalibratedRig:
    """The rig of the generator's [rig] settings (dotsim.rig.config.RigConfig; docs/CONFIG.md): the
    preset or `file`; the camera of `camera_file`; the projector and its pose of `projector_file`;
    sizes a file lacks from <role>_width / <role>_height; explicit camera / projector intrinsics,
    projector offsets and rotation, max_depth; checked (check_rig, and square camera pixels, which the
    renderer needs), then scaled. Its sources name the preset, files and keys each part came from.

    Zero means "keep": a non-zero offset replaces the base rig's, non-zero angles replace its
    rotation. Raises RigFileError naming `where` and the key.
    """
    try:
        base = (_file_parts(settings.file, ("camera", "projector"), None) if settings.file
                else _preset_parts(settings.preset))
    except RigFileError as error:
        raise RigFileError(f"{where} file: {error}") from None
    try:
        parts = _composed(base, settings.camera_file, settings.projector_file)
    except RigFileError as error:
        raise RigFileError(f"{where} {error}") from None
    # <role>_width, _height, _fx, _fy, _cx, _cy (_INTRINSICS_KEYS) of each role
    explicit = {"camera": (settings.camera_width, settings.camera_height, settings.camera_fx,
                           settings.camera_fy, settings.camera_cx, settings.camera_cy),
                "projector": (settings.projector_width, settings.projector_height, settings.projector_fx,
                              settings.projector_fy, settings.projector_cx, settings.projector_cy)}
    # width and height without a focal length: the size of a file's camera that gives none
    sizes = tuple(values[:2] if values[0] and not values[2] else None for values in explicit.values())
    try:
        calibrated = _calibrated(parts, where, sizes)
    except RigFileError as error:
        raise RigFileError(f"{where}: {error}") from None
    base = calibrated.rig
    offsets = (settings.baseline, settings.projector_y, settings.projector_z)
    translation = [value if value != 0.0 else kept for value, kept in
                   zip(offsets, base.projector_translation, strict=True)]
    angles = (settings.projector_rotation_x, settings.projector_rotation_y, settings.projector_rotation_z)
    rotation = rotation_matrix(*np.radians(angles)) if any(angles) else base.projector_rotation
    camera = _explicit_intrinsics("camera", explicit["camera"], where)
    try:
        projector = _explicit_intrinsics("projector", explicit["projector"], where)
        rig = replace(base, camera=camera or base.camera, projector=projector or base.projector,
                      projector_translation=tuple(translation), projector_rotation=rotation,
                      max_depth=settings.max_depth)
    except ValueError as error:
        raise RigFileError(f"{where}: {error}") from None
    check_rig(rig, where)
    try:
        check_square_pixels(rig.camera.fx, rig.camera.fy)
    except ValueError as error:
        raise RigFileError(f"{where}: {error}") from None
    sources = dict(calibrated.sources)
    for part, given, keys in (("camera", camera, "camera_width, camera_height, camera_fx ..."),
                              ("projector", projector, "projector_width, projector_height, projector_fx ..."),
                              ("pose", any(offsets) or any(angles), "baseline, projector_y ... (non-zero)")):
        if given:
            sources[part] = f"{sources[part]}, then {where} {keys}" if part == "pose" else f"{where} {keys}"
    sources["max depth"] = f"{where} max_depth"
    calibrated = CalibratedRig(rig, None if camera else calibrated.lens, tuple(sources.items()),
                               calibrated.notes)
    return calibrated.scaled(settings.scale) if settings.scale != 1.0 else calibrated


def _explicit_intrinsics(role: str, given: tuple, where: str) -> Intrinsics | None:
    """The [rig] <role>_width ... <role>_cy values `given` (in _INTRINSICS_KEYS' order) as Intrinsics,
    or None when no focal length or principal point is set (width and height alone give the size of
    a file's camera that lacks one)."""
    values = dict(zip(_INTRINSICS_KEYS, given, strict=True))
    if not any(values[key] for key in ("fx", "fy", "cx", "cy")):
        return None
    if missing := [f"{role}_{key}" for key in ("width", "height", "fx") if not values[key]]:
        raise RigFileError(f"{where}: an explicit {role} needs {', '.join(missing)} as well (set "
                           f"{role}_width, {role}_height and {role}_fx, or none of the {role}_* keys)")
    if not values["fy"]:
        values["fy"] = values["fx"]
    if not values["cx"] and not values["cy"]:
        values["cx"], values["cy"] = values["width"] / 2 - 0.5, values["height"] / 2 - 0.5
    return Intrinsics(**values)


def device_rig(name: str, camera: Intrinsics, projector_translation, second_camera_translation=None,
               max_depth: float = DEFAULT_MAX_DEPTH) -> Rig:
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

    Checks: principal points inside their images; a positive baseline (the projector at +x); the
    projector facing the scene the camera sees
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
    if rig.baseline <= 0:
        raise RigFileError(f"{where}: the projector's x offset (baseline) is {rig.baseline:g} m; allowed: "
                           "> 0, the projector to the camera's right (image +x): at 0 no dot moves with "
                           "depth (disparity 0 everywhere); dotsim's disparity is positive for a projector "
                           "at +x")
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
