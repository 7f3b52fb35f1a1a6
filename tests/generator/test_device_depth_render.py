"""The device's own depth on real tiny Cycles renders (`dotsim generate` with [device_depth] on): the
frames carry device_depth beside the channels the same config writes without it, byte for byte; no
depth over the band the disparity search implies; where the device reports depth, it is the rendered
ground truth's, to the precision the device's disparity step allows at that depth."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dotsim import config_schema, dataset
from dotsim.channels import rendered_channels
from dotsim.device_depth import DeviceDepthConfig, search_range
from dotsim.rig.presets import get_preset
from generator.config import config_from_dict
from generator.driver import generate

REPO = Path(__file__).resolve().parents[2]
TINY = REPO / "dotsim" / "configs" / "tiny.toml"
SCALE = 0.1


def tiny(preset: str, stereo: bool, device_depth: dict, scale: float = SCALE):
    data = config_schema.read_toml(TINY)
    data["rig"] = {"preset": preset, "scale": scale, "stereo": stereo}
    data["device_depth"] = device_depth
    return config_from_dict(data, source=str(TINY), base_dir=REPO)


def frames_of(out: Path):
    return dataset.read_scene(dataset.open_dataset(out).scenes[0].path)


def check_against_truth(frame: dict, fx_b: float, band: int, step: float) -> None:
    device, truth = frame["device_depth"], frame["depth"]
    assert np.isnan(device[:, :band]).all()
    reported = np.isfinite(device) & np.isfinite(truth)
    assert reported.mean() > 0.05, "the device reports depth somewhere"
    # the reported disparity against the truth's: within a step and a half on most pixels (edges and
    # mismatches aside), its median within half a step
    error = np.abs(fx_b / device[reported] - fx_b / truth[reported])
    assert np.median(error) <= step / 2 + 0.05 and (error <= 1.5 * step + 0.1).mean() > 0.8, \
        (np.median(error), (error <= 1.5 * step + 0.1).mean())


def test_a_stereo_render_carries_the_devices_depth_and_nothing_else_changes(tmp_path):
    engine = {"engine": "stereo", "subpixel_step": 0.125}
    plain, device = tmp_path / "plain", tmp_path / "device"
    assert generate(tiny("realsense_d415", True, {}), plain, "train", 1, seed=2, progress=False).done == 1
    assert generate(tiny("realsense_d415", True, engine), device, "train", 1, seed=2,
                    progress=False).done == 1
    scene, alone = frames_of(device), frames_of(plain)
    assert set(scene.meta["channels"]) == set(rendered_channels(True, ("device_depth",)))
    assert set(alone.meta["channels"]) == set(rendered_channels(stereo=True))
    rig = get_preset("realsense_d415").scaled(SCALE)
    low, count = search_range(DeviceDepthConfig(**engine), SCALE)
    for frame, plain_frame in zip(scene.frames, alone.frames, strict=True):
        for name, value in plain_frame.items():
            np.testing.assert_array_equal(frame[name], value, err_msg=name)
        check_against_truth(frame, rig.camera.fx * 0.055, low + count - 1, 0.125)


def test_a_structured_light_render_carries_the_devices_depth(tmp_path):
    """Kinect v1 at scale 0.25 (160 x 120, fx b = 10.9 px m): 96 disparities are 24 there, searched as
    32 (0 .. 31); against the reference at 2 m (5.44 px) the matcher's relative disparities start at
    floor(0 - 5.44) = -6, so the left band is -6 + 32 - 1 = 25 columns wide."""
    engine = {"engine": "structured_light", "num_disparities": 96, "subpixel_step": 0.125,
              "reference_distance": 2.0}
    out = tmp_path / "d"
    assert generate(tiny("kinect_v1", False, engine, 0.25), out, "train", 1, seed=2, progress=False).done == 1
    scene = frames_of(out)
    assert "device_depth" in scene.meta["channels"]
    rig = get_preset("kinect_v1").scaled(0.25)
    for frame in scene.frames:
        check_against_truth(frame, rig.camera.fx * rig.baseline, 25, 0.125)
