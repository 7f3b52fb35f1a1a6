"""Sensor rig geometry: an IR camera, a dot projector beside it, and the conversions between
depth, disparity and projector column. Pure numpy.

Conventions (docs/GEOMETRY.md has the derivations):
- Camera frame is OpenCV's: x right, y down, z forward, metres. Pixel (row i, col j) is centred at
  (u=j, v=i); with Blender's principal point at the image centre, cx = W/2 - 0.5, cy = H/2 - 0.5.
- Depth is planar depth z (not ray length), metres. Missing depth is inf or nan.
- The projector is a pinhole "camera" with its own intrinsics (pattern resolution). Its pose:
  X_proj = R @ (X_cam - t), t = projector centre in the camera frame, R = projector_rotation.
  The projector frame is also OpenCV-like, so pattern row 0 is the top of the projector image.
- Disparity d = fx * b / z (camera px, b = t_x). With the projector at +x, camera column u sees
  pattern column u - d of the pattern as seen from infinity: nearer surfaces move dots right.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from dotsim.config_schema import REQUIRED, Checked, check, record_from_dict, setting

Vector3 = tuple[float, float, float]
Matrix3 = tuple[Vector3, Vector3, Vector3]

IDENTITY: Matrix3 = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
# A rig's max_depth when its source gives none (a calibration file, `dotsim capture info`), m.
DEFAULT_MAX_DEPTH = 20.0


@dataclass(frozen=True)
class Intrinsics(Checked):
    """Pinhole intrinsics of a camera or projector: image size (px) and focal/principal point (px),
    checked on construction (dotsim.config_schema)."""

    width: int = setting(REQUIRED, "image width, px", low=1)
    height: int = setting(REQUIRED, "image height, px", low=1)
    fx: float = setting(REQUIRED, "focal length along x, px", low=0.0, low_open=True)
    fy: float = setting(REQUIRED, "focal length along y, px", low=0.0, low_open=True)
    cx: float = setting(REQUIRED, "principal point column, px")
    cy: float = setting(REQUIRED, "principal point row, px")

    @classmethod
    def centred(cls, width: int, height: int, focal: float) -> Intrinsics:
        """Square pixels, principal point at the image centre (what Blender renders)."""
        return cls(width, height, focal, focal, width / 2 - 0.5, height / 2 - 0.5)

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def scaled(self, factor: float) -> Intrinsics:
        """Same field of view at about `factor` times the resolution (for tiny test renders).

        Sizes are rounded to whole pixels. The focal length scales by `factor` (square pixels stay
        square, which Blender needs); the principal point scales by the actual size ratio per axis,
        cx' = (cx + 0.5) * W'/W - 0.5, so a centred principal point stays exactly centred. When
        W * factor is a whole number this is cx' = (cx + 0.5) * factor - 0.5.
        """
        factor = check(factor, float, "factor", low=0.0, low_open=True)
        width = max(1, round(self.width * factor))
        height = max(1, round(self.height * factor))
        return Intrinsics(
            width,
            height,
            self.fx * factor,
            self.fy * factor,
            (self.cx + 0.5) * width / self.width - 0.5,
            (self.cy + 0.5) * height / self.height - 0.5,
        )


def check_square_pixels(fx: float, fy: float) -> None:
    """ValueError unless fx and fy agree (to 1e-6 relative): Blender renders square pixels, so a
    camera the generator renders must have them."""
    if abs(fx - fy) > 1e-6 * fx:
        raise ValueError(f"camera fx = {fx:g} differs from fy = {fy:g}; allowed: equal focal lengths "
                         "(Blender renders square pixels)")


def rotation_matrix(rx: float, ry: float, rz: float) -> Matrix3:
    """Rotation R = Rz @ Ry @ Rx from angles in radians (about x, then y, then z; Blender's XYZ)."""
    cx, sx = math.cos(rx), math.sin(rx)
    cy, sy = math.cos(ry), math.sin(ry)
    cz, sz = math.cos(rz), math.sin(rz)
    r_x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    r_y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    r_z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return tuple(tuple(float(v) for v in row) for row in r_z @ r_y @ r_x)  # type: ignore[return-value]


def is_rotation(matrix) -> bool:
    """Whether a 3x3 matrix is what a Rig takes as projector_rotation: orthonormal (R R^T = I to
    numpy.allclose with atol 1e-6) and proper (det > 0)."""
    matrix = np.asarray(matrix, np.float64)
    return bool(np.allclose(matrix @ matrix.T, np.eye(3), atol=1e-6) and np.linalg.det(matrix) > 0)


@dataclass(frozen=True)
class Rig(Checked):
    """An IR camera with a dot projector (and optionally a second IR camera) rigidly beside it,
    checked on construction (dotsim.config_schema; the rotation must be proper)."""

    name: str = setting(REQUIRED, "the rig's name", min_items=1)
    camera: Intrinsics
    projector: Intrinsics
    projector_translation: Vector3 = setting(REQUIRED, "projector centre in the camera frame, m")
    projector_rotation: Matrix3 = setting(IDENTITY, "R with X_proj = R @ (X_cam - t), rows; identity for "
                                          "a rectified rig")
    second_camera_translation: Vector3 | None = setting(None, "second IR camera centre in the camera "
                                                        "frame, m (same orientation), or None")
    # The one declaration of max_depth's bounds: the config's [rig] max_depth takes them (bounds_of).
    max_depth: float = setting(DEFAULT_MAX_DEPTH, "farthest depth used for training and ground truth, m",
                               low=0.5, high=1000.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("camera", "projector"):
            if not isinstance(getattr(self, name), Intrinsics):
                raise ValueError(f"rig {name} must be Intrinsics, got {type(getattr(self, name)).__name__}")
        if not is_rotation(self.projector_rotation):
            raise ValueError(f"projector_rotation must be a proper rotation (orthonormal, det +1), "
                             f"got {[list(row) for row in self.projector_rotation]!r}")

    @property
    def baseline(self) -> float:
        """Camera-projector baseline b (metres): the x component of the projector translation."""
        return self.projector_translation[0]

    @property
    def R(self) -> np.ndarray:
        return np.array(self.projector_rotation)

    @property
    def t(self) -> np.ndarray:
        return np.array(self.projector_translation)

    @property
    def is_rectified(self) -> bool:
        """True when the projector is only shifted along camera x (the closed-form disparity case)."""
        return self.projector_rotation == IDENTITY and self.projector_translation[1:] == (0.0, 0.0)

    def scaled(self, factor: float) -> Rig:
        """The same rig at about `factor` times the camera AND projector resolution (same fields of view);
        a pattern for the scaled rig must have the scaled projector's resolution."""
        return replace(self, camera=self.camera.scaled(factor), projector=self.projector.scaled(factor))

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict; Rig.from_dict(rig.to_dict()) == rig exactly (floats survive JSON)."""
        return {
            "name": self.name,
            "camera": self.camera.to_dict(),
            "projector": self.projector.to_dict(),
            "projector_translation": list(self.projector_translation),
            "projector_rotation": [list(row) for row in self.projector_rotation],
            "second_camera_translation": (None if self.second_camera_translation is None
                                          else list(self.second_camera_translation)),
            "max_depth": self.max_depth,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "rig") -> Rig:
        """Inverse of to_dict; a missing or unknown key or a bad value raises ConfigError (a
        ValueError) naming it and the value."""
        return record_from_dict(cls, d, where, optional=("projector_rotation", "second_camera_translation",
                                                          "max_depth"),
                                camera=Intrinsics.from_dict, projector=Intrinsics.from_dict)


def is_ground_truth(depth: np.ndarray, max_depth: float) -> np.ndarray:
    """Where a depth map (metres) is ground truth: bool, True where the depth is finite, > 0 and at
    most max_depth (a rig's max_depth, the farthest depth trained on and scored). The one rule of the
    stored and derived ground-truth channels, the stereo disparity, `dotsim stats` and point clouds.

    >>> is_ground_truth(np.array([0.5, 20.0, 20.5, np.inf, np.nan, 0.0]), 20.0)
    array([ True,  True, False, False, False, False])
    """
    depth = np.asarray(depth)
    return np.isfinite(depth) & (depth > 0) & (depth <= max_depth)


def _valid_depth(depth: np.ndarray) -> np.ndarray:
    """float64 copy of depth with non-finite and non-positive values set to nan."""
    depth = np.asarray(depth, dtype=np.float64)
    return np.where(np.isfinite(depth) & (depth > 0), depth, np.nan)


def depth_to_disparity(depth: np.ndarray, rig: Rig) -> np.ndarray:
    """Disparity d = fx * b / z in camera px (float32); nan where depth is non-finite or <= 0.

    For a rotated projector this is the rectified-equivalent disparity (same formula); the exact
    pattern position is depth_to_projector_column."""
    return (rig.camera.fx * rig.baseline / _valid_depth(depth)).astype(np.float32)


def disparity_to_depth(disparity: np.ndarray, rig: Rig) -> np.ndarray:
    """Depth z = fx * b / d in metres (float32); nan where disparity is non-finite or <= 0."""
    return depth_to_disparity(disparity, rig)  # the formula is its own inverse: z = fx b / d


def pixel_grid(intrinsics: Intrinsics, supersample: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates (u, v), each (H*s, W*s) float64, s = supersample.

    Sample (i*s + a, j*s + b) sits at u = j + (b + 0.5)/s - 0.5, v = i + (a + 0.5)/s - 0.5: an s x s
    grid of sub-pixel centres inside pixel (i, j); average with .reshape(H, s, W, s).mean((1, 3)).
    """
    s = check(supersample, int, "supersample", low=1)
    u = (np.arange(intrinsics.width * s) + 0.5) / s - 0.5
    v = (np.arange(intrinsics.height * s) + 0.5) / s - 0.5
    return np.meshgrid(u, v)


def pixel_rays(u: np.ndarray, v: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """Camera-frame ray directions (..., 3) with z = 1 through pixel coordinates (u, v)."""
    u, v = np.broadcast_arrays(np.asarray(u, np.float64), np.asarray(v, np.float64))
    return np.stack([(u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy,
                     np.ones_like(u)], axis=-1)


def backproject(depth: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """Camera-frame 3D points (H, W, 3) float64 of a planar depth map (H, W) in metres; nan where the
    depth is non-finite or <= 0."""
    depth = _valid_depth(depth)
    if depth.shape != (intrinsics.height, intrinsics.width):
        raise ValueError(f"depth shape {depth.shape} != camera (height, width) "
                         f"{(intrinsics.height, intrinsics.width)}")
    return _camera_rays(intrinsics) * depth[..., None]


@functools.lru_cache(maxsize=4)
def _camera_rays(intrinsics: Intrinsics) -> np.ndarray:
    """pixel_rays of every pixel centre of a camera (read-only): made once per camera, since a
    generator post-renders thousands of frames of one rig."""
    rays = pixel_rays(*pixel_grid(intrinsics), intrinsics)
    rays.flags.writeable = False
    return rays


def camera_to_projector_frame(points_cam: np.ndarray, rig: Rig) -> np.ndarray:
    """Points (..., 3) from the camera frame into the projector frame: R @ (X - t)."""
    return (np.asarray(points_cam, np.float64) - rig.t) @ rig.R.T


def _pinhole_project(points: np.ndarray, intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (x, y) of points (..., 3) in a pinhole's own frame; nan where z <= 0."""
    z = points[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        in_front = z > 0
        x = np.where(in_front, intrinsics.fx * points[..., 0] / z + intrinsics.cx, np.nan)
        y = np.where(in_front, intrinsics.fy * points[..., 1] / z + intrinsics.cy, np.nan)
    return x, y


def project_to_projector(points_cam: np.ndarray, rig: Rig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Projector pixel coordinates (xp, yp) and projector-frame depth zp of camera-frame points
    (..., 3). xp, yp are nan where zp <= 0 (behind the projector) or the point is nan; values outside
    the projector image are kept (callers decide what is in the frustum)."""
    points = camera_to_projector_frame(points_cam, rig)
    xp, yp = _pinhole_project(points, rig.projector)
    return xp, yp, points[..., 2]


def depth_to_projector_column(depth: np.ndarray, rig: Rig, normalised: bool = False) -> np.ndarray:
    """Projector column (float32, projector px; or px / projector width when normalised) that lights
    each camera pixel of a planar depth map; nan where the depth is invalid. Columns outside the
    projector image are kept (the visibility mask says where dots really land)."""
    xp, _, _ = project_to_projector(backproject(depth, rig.camera), rig)
    if normalised:
        xp = xp / rig.projector.width
    return xp.astype(np.float32)


def projector_column_to_depth(column: np.ndarray, rig: Rig, normalised: bool = False) -> np.ndarray:
    """Planar depth (float32, metres) at each camera pixel from the projector column lighting it.

    The projector column xp is a plane through the projector centre; in the projector frame its
    normal is m = (1, 0, -a), a = (xp - cxp) / fxp. The camera ray X = z r (r = (x', y', 1)) meets it
    where m . R (z r - t) = 0, so z = n.t / n.r with n = R^T m. For a rectified rig (R = I,
    t = (b, 0, 0)) this is z = fxp b / (fxp (u - cx)/fx + cxp - xp). nan where the column is
    non-finite, the ray is parallel to the plane or z <= 0.
    """
    column = np.asarray(column, np.float64)
    if column.shape != (rig.camera.height, rig.camera.width):
        raise ValueError(f"column shape {column.shape} != camera (height, width) "
                         f"{(rig.camera.height, rig.camera.width)}")
    xp = column * rig.projector.width if normalised else column
    a = (xp - rig.projector.cx) / rig.projector.fx
    m = np.stack([np.ones_like(a), np.zeros_like(a), -a], axis=-1)
    n = m @ rig.R  # n = R^T m for each pixel, as row vectors
    u, v = pixel_grid(rig.camera)
    rays = pixel_rays(u, v, rig.camera)
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = (n @ rig.t) / np.einsum("...k,...k->...", n, rays)
    return np.where(np.isfinite(depth) & (depth > 0), depth, np.nan).astype(np.float32)


def bilinear_sample(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear lookup of image (H, W) at pixel coordinates (x = column, y = row; pixel centres at
    integers). Zero outside the image's extent [-0.5, W - 0.5] x [-0.5, H - 0.5] and at nan
    coordinates; inside the half-pixel border the edge pixel is repeated (like a clipped texture)."""
    image = np.asarray(image)
    height, width = image.shape
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    inside = (x >= -0.5) & (x <= width - 0.5) & (y >= -0.5) & (y <= height - 0.5)
    xc = np.clip(np.where(inside, x, 0.0), 0, width - 1)
    yc = np.clip(np.where(inside, y, 0.0), 0, height - 1)
    x0 = np.floor(xc).astype(np.intp)
    y0 = np.floor(yc).astype(np.intp)
    x1 = np.minimum(x0 + 1, width - 1)
    y1 = np.minimum(y0 + 1, height - 1)
    fx = xc - x0
    fy = yc - y0
    top = image[y0, x0] * (1 - fx) + image[y0, x1] * fx
    bottom = image[y1, x0] * (1 - fx) + image[y1, x1] * fx
    return np.where(inside, top * (1 - fy) + bottom * fy, 0.0)


def check_pattern_shape(pattern_image: np.ndarray, rig: Rig) -> np.ndarray:
    """The pattern as a 2-D float array; ValueError unless its shape is the projector's (H, W)."""
    pattern_image = np.asarray(pattern_image, np.float64)
    expected = (rig.projector.height, rig.projector.width)
    if pattern_image.shape != expected:
        raise ValueError(f"pattern shape {pattern_image.shape} != projector (height, width) {expected} "
                         f"of rig {rig.name!r}")
    return pattern_image


def reference_image(pattern_image: np.ndarray, rig: Rig, supersample: int = 1) -> np.ndarray:
    """The pattern as seen from infinity, in camera pixels (H, W) float32: what SGBM matches against.

    Each camera ray (its direction only: the translation does not matter at infinity) is rotated into
    the projector frame and looked up bilinearly in the pattern; zero outside the projector image.
    For a rectified rig a dot at camera column u in this image appears at u + d on a surface at depth
    z (d = fx b / z). supersample s averages s x s rays per pixel (the pattern has finer pixels than
    the camera).
    """
    pattern_image = check_pattern_shape(pattern_image, rig)
    u, v = pixel_grid(rig.camera, supersample)
    directions = pixel_rays(u, v, rig.camera) @ rig.R.T
    xp, yp = _pinhole_project(directions, rig.projector)
    samples = bilinear_sample(pattern_image, xp, yp)
    s = supersample
    return samples.reshape(rig.camera.height, s, rig.camera.width, s).mean(axis=(1, 3)).astype(np.float32)
