"""dotsim.rig.colour_camera: the pose convention against an independent construction, checks on
construction, the presets' colour cameras and their sources."""

import doctest
import json
import math

import numpy as np
import pytest

from dotsim.rig import colour_camera
from dotsim.rig.colour_camera import ColourCamera
from dotsim.rig.geometry import Intrinsics
from dotsim.rig.presets import PRESET_COLOUR_CAMERAS, PRESET_DIR


def test_doctests():
    assert doctest.testmod(colour_camera).failed == 0


def test_a_turned_and_shifted_camera_projects_as_its_pose_says():
    """A colour camera 3 cm right of the IR camera and turned 10 degrees about its y axis: a point on its
    optical axis 2 m away (built from the pose by hand) lands on its principal point, and a point 0.1 m
    to its right on the row of its principal point, f * 0.1 / 2 px to the right."""
    angle = math.radians(10.0)
    cos, sin = math.cos(angle), math.sin(angle)
    rotation = ((cos, 0.0, sin), (0.0, 1.0, 0.0), (-sin, 0.0, cos))
    camera = ColourCamera(Intrinsics.centred(64, 48, 50.0), translation=(0.03, 0.0, 0.0), rotation=rotation)
    axis_z = np.array([math.sin(angle), 0.0, math.cos(angle)])  # its z axis in the IR frame: R's third column
    axis_x = np.array([math.cos(angle), 0.0, -math.sin(angle)])
    centre = np.array([0.03, 0.0, 0.0])
    np.testing.assert_allclose(camera.project(centre + 2.0 * axis_z), [31.5, 23.5], atol=1e-9)
    np.testing.assert_allclose(camera.project(centre + 2.0 * axis_z + 0.1 * axis_x), [31.5 + 50 * 0.05, 23.5],
                               atol=1e-9)
    world_from_ir = np.eye(4)
    world_from_ir[:3, 3] = (1.0, 2.0, 3.0)
    np.testing.assert_allclose(camera.pose(world_from_ir)[:3, 3], (1.03, 2.0, 3.0))
    assert ColourCamera.from_dict(json.loads(json.dumps(camera.to_dict()))) == camera


@pytest.mark.parametrize("change, message", [
    ({"intrinsics": Intrinsics(64, 48, 50.0, 51.0, 31.5, 23.5)}, "fx = 50 differs from fy = 51"),
    ({"rotation": ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, -1.0))}, "must be a proper rotation"),
])
def test_bad_cameras_are_refused_naming_the_value(change, message):
    fields = {"intrinsics": Intrinsics.centred(64, 48, 50.0), **change}
    with pytest.raises(ValueError, match=message):
        ColourCamera(**fields)


def test_the_rgbd_presets_have_their_colour_camera_and_its_sources():
    assert sorted(PRESET_COLOUR_CAMERAS) == ["kinect_v1", "realsense_d415", "realsense_d435"]
    d415 = PRESET_COLOUR_CAMERAS["realsense_d415"].intrinsics
    # 69.4 degrees across 1920 px (the datasheet's colour field)
    assert (d415.width, d415.height) == (1920, 1080)
    assert math.degrees(2 * math.atan(960 / d415.fx)) == pytest.approx(69.4, abs=0.01)
    assert PRESET_COLOUR_CAMERAS["kinect_v1"].translation == (0.025, 0.0, 0.0)
    for name in PRESET_COLOUR_CAMERAS:
        notes = json.loads((PRESET_DIR / f"{name}.json").read_text())["colour_notes"]
        assert "issue" in notes or "camera_params.m" in notes  # a public calibration or datasheet named
        scaled = PRESET_COLOUR_CAMERAS[name].scaled(0.5)
        assert scaled.translation == PRESET_COLOUR_CAMERAS[name].translation
        assert scaled.intrinsics.width == round(PRESET_COLOUR_CAMERAS[name].intrinsics.width / 2)
