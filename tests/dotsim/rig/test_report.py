"""dotsim.rig.report: the rig as people read it; fields of view against OpenCV's own."""

import doctest
from dataclasses import replace

import cv2
import numpy as np
import pytest

from dotsim.rig import report
from dotsim.rig.files import composed_rig
from dotsim.rig.geometry import Intrinsics, rotation_matrix
from dotsim.rig.presets import PRESETS


def test_doctests():
    result = doctest.testmod(report)
    assert result.attempted > 0 and result.failed == 0


@pytest.mark.parametrize("intrinsics", [*(rig.camera for rig in PRESETS.values()),
                                        Intrinsics(640, 480, 602.5, 598.5, 321.3, 238.9)])
def test_fields_of_view_are_opencvs(intrinsics):
    """cv2.calibrationMatrixValues measures from the image's edges with the principal point in edge
    coordinates: ours (pixel centres at integers) plus half a pixel."""
    K = intrinsics.K.copy()
    K[:2, 2] += 0.5
    fovx, fovy, *_ = cv2.calibrationMatrixValues(K, (intrinsics.width, intrinsics.height), 1.0, 1.0)
    np.testing.assert_allclose(report.field_of_view(intrinsics), (fovx, fovy), rtol=1e-12)


def test_report_lists_every_part_with_its_source_and_the_rotation():
    calibrated = composed_rig("realsense_d415")
    lines = report.report_lines(calibrated)
    assert [line.split()[0] for line in lines] == ["rig", "camera", "projector", "pose", "second", "max"]
    assert all(line.endswith("[from preset realsense_d415]") for line in lines[1:])
    rig = PRESETS["realsense_d415"]
    assert f"baseline {rig.baseline:+.4f} m" in lines[3] and "rotated 0.000 deg" in lines[3]
    rotated = replace(rig, projector_rotation=rotation_matrix(0.0, np.radians(2), 0.0))
    assert report.rotation_angle(rotated) == pytest.approx(2.0, abs=1e-9)
