"""The preset rigs against their sources: the Structure Core's values, the RealSense datasheets, and the
presets' rule for projectors (docs/GEOMETRY.md "Presets")."""

import doctest
import math

import pytest

from dotsim.rig import presets
from dotsim.rig.presets import PRESETS, get_preset


def test_structure_core_preset_values():
    rig = get_preset()
    assert rig.name == "structure_core"
    assert (rig.camera.width, rig.camera.height) == (1216, 896)
    assert rig.camera.fx == rig.camera.fy == 1115.44
    assert (rig.camera.cx, rig.camera.cy) == (607.5, 447.5)  # Blender's image centre
    assert (rig.projector.width, rig.projector.height, rig.projector.fx) == (3072, 3072, 2230.88)
    assert rig.baseline == 0.0634 and rig.second_camera_translation == (0.07501, 0.0, 0.0)
    assert rig.max_depth == 20.0 and rig.is_rectified


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_every_preset_is_centred_and_the_projector_covers_the_camera(name):
    """Projectors drawn by the presets' rule have a field wider than the camera's; the D435's is its
    real one, the datasheet's wide projector (86 deg against the camera's 87)."""
    rig = PRESETS[name]
    for intr in (rig.camera, rig.projector):
        assert (intr.cx, intr.cy) == (intr.width / 2 - 0.5, intr.height / 2 - 0.5)
    camera_half_fov = math.atan(rig.camera.width / 2 / rig.camera.fx)
    projector_half_fov = math.atan(rig.projector.width / 2 / rig.projector.fx)
    assert projector_half_fov > camera_half_fov or name == "realsense_d435"
    assert rig.baseline > 0


def _degrees(size: int, focal: float) -> float:
    return math.degrees(2 * math.atan(size / 2 / focal))


@pytest.mark.parametrize("name, hfov, baseline", [("realsense_d415", 65.0, 0.055),
                                                  ("realsense_d435", 87.0, 0.05)])
def test_realsense_presets_follow_the_datasheet(name, hfov, baseline):
    """D400 datasheet: depth field of view 65 / 87 deg across 1280 px, imagers 55 / 50 mm apart; the
    projector between them (its midpoint: the datasheet gives no offset), all on the x axis."""
    rig = get_preset(name)
    assert _degrees(rig.camera.width, rig.camera.fx) == pytest.approx(hfov, abs=0.01)
    assert rig.second_camera_translation == (baseline, 0.0, 0.0)
    assert rig.projector_translation == (baseline / 2, 0.0, 0.0) and rig.is_rectified


def test_d435_projector_is_the_datasheets_wide_projector():
    projector = get_preset("realsense_d435").projector
    assert _degrees(projector.width, projector.fx) == pytest.approx(86.0, abs=0.05)
    assert _degrees(projector.height, projector.fy) == pytest.approx(57.0, abs=0.05)


def test_unknown_preset_names_the_choices():
    with pytest.raises(ValueError, match="unknown rig preset 'nope'.*structure_core"):
        get_preset("nope")


def test_the_docstring_example():
    result = doctest.testmod(presets)
    assert result.attempted > 0 and result.failed == 0


def test_ctd_synthetic_is_depthinspace_camera_standing_upright():
    """DepthInSpace's synthetic camera (its data generator's imsize (512, 432) is (height, width), K with
    f 435.2 and principal point (216, 256) = (W/2, H/2)): 432 px wide, 512 px tall; the projector keeps
    the presets' rule of 2 pattern px per camera px, so its image stands upright too."""
    rig = get_preset("ctd_synthetic")
    assert (rig.camera.width, rig.camera.height, rig.camera.fx, rig.camera.fy) == (432, 512, 435.2, 435.2)
    assert (rig.camera.cx + 0.5, rig.camera.cy + 0.5) == (216, 256)  # DepthInSpace's K, pixel centres at +0.5
    assert rig.projector.fx == 2 * rig.camera.fx and rig.projector.height > rig.projector.width
    assert rig.baseline == 0.025 and rig.max_depth == 6.0
