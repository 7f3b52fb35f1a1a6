"""A resolved rig as people read it: the one-line summary `dotsim generate` prints when it starts and
the listing of `dotsim rig show` (intrinsics, fields of view, baseline, pose, second camera, max depth,
and which preset, file or config key each part came from). Pure numpy.

>>> from dotsim.rig.files import composed_rig
>>> print(summary_line(composed_rig("kinect_v1")))  # doctest: +NORMALIZE_WHITESPACE
rig kinect_v1: camera 640 x 480 px, f 580.00 px, field of view 57.8 x 45.0 deg; projector 1600 x 1200
px, f 1160.00 px, field of view 69.2 x 54.7 deg; baseline +0.0750 m; max depth 8 m
"""

from __future__ import annotations

import math

import numpy as np

from dotsim.rig.files import RIG_PARTS, CalibratedRig
from dotsim.rig.geometry import Intrinsics, Rig


def field_of_view(intrinsics: Intrinsics) -> tuple[float, float]:
    """Horizontal and vertical field of view in degrees, from edge to edge of the image (pixel centres
    0 .. W - 1, so the edges lie half a pixel beyond), about the principal point."""
    def span(centre: float, size: int, focal: float) -> float:
        return math.degrees(math.atan((centre + 0.5) / focal) + math.atan((size - 0.5 - centre) / focal))

    return (span(intrinsics.cx, intrinsics.width, intrinsics.fx),
            span(intrinsics.cy, intrinsics.height, intrinsics.fy))


def rotation_angle(rig: Rig) -> float:
    """The angle of the projector's rotation against the camera, degrees (0: a rectified rig)."""
    cosine = (float(np.trace(rig.R)) - 1) / 2
    return math.degrees(math.acos(min(1.0, max(-1.0, cosine))))


def _optics(intrinsics: Intrinsics) -> str:
    h, v = field_of_view(intrinsics)
    focal = (f"f {intrinsics.fx:.2f} px" if intrinsics.fx == intrinsics.fy
             else f"fx {intrinsics.fx:.2f} fy {intrinsics.fy:.2f} px")
    return f"{intrinsics.width} x {intrinsics.height} px, {focal}, field of view {h:.1f} x {v:.1f} deg"


def summary_line(calibrated: CalibratedRig) -> str:
    """One line: the rig's name, camera and projector (size, focal length, field of view), baseline and
    max depth."""
    rig = calibrated.rig
    return (f"rig {rig.name}: camera {_optics(rig.camera)}; projector {_optics(rig.projector)}; "
            f"baseline {rig.baseline:+.4f} m; max depth {rig.max_depth:g} m")


def _vector(values) -> str:
    return "(" + ", ".join(f"{v:+.4f}" for v in values) + ") m"


def report_lines(calibrated: CalibratedRig) -> list[str]:
    """`dotsim rig show`'s listing: one line per part (RIG_PARTS, the lens between camera and projector)
    with where it came from, then the rig's notes."""
    rig, lens = calibrated.rig, calibrated.lens

    def principal(intrinsics: Intrinsics) -> str:
        return f"principal point ({intrinsics.cx:.2f}, {intrinsics.cy:.2f})"

    second = rig.second_camera_translation
    angle = rotation_angle(rig)
    values = {
        "camera": f"{_optics(rig.camera)}, {principal(rig.camera)}",
        "projector": f"{_optics(rig.projector)}, {principal(rig.projector)}",
        "pose": (f"projector centre {_vector(rig.projector_translation)} in the camera frame (baseline "
                 f"{rig.baseline:+.4f} m), rotated {angle:.3f} deg"
                 + ("" if angle == 0 else f" (R = {np.round(rig.R, 6).tolist()})")),
        "second camera": "none" if second is None else f"centre {_vector(second)}, oriented as the camera",
        "max depth": f"{rig.max_depth:g} m",
    }
    lines = [f"{'rig':<14} {rig.name}"]
    for part in RIG_PARTS:
        source = calibrated.source(part)
        lines.append(f"{part:<14} {values[part]}" + (f"   [from {source}]" if source else ""))
        if part == "camera" and lens is not None:
            given = lens.intrinsics
            lines.append(f"{'  lens':<14} {lens.model} distortion {list(lens.distortion)}, fx {given.fx:.2f} "
                         f"fy {given.fy:.2f}: real frames are rectified to the camera above, which renders")
    return lines + [f"note: {note}" for note in calibrated.notes]
