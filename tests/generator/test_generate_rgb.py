"""`dotsim generate` with the colour camera ([render] rgb) on a real tiny scene: scene.json records the
colour camera, the frame file holds its image in a part of its own size, and every reader carries it:
read_frame, the export and its reader, the frame source, `dotsim show` and `dotsim view`; the config
refuses a rig without a colour camera in one line; frames without it stay single-part as before."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace

import numpy as np
import OpenEXR
import pytest

from commands.show import contact_sheet
from dotsim import dataset
from dotsim.channels import rendered_channels
from dotsim.config_schema import read_toml
from dotsim.configs import config_path
from dotsim.false_colour import colour_image
from dotsim.frame_source import open_source
from dotsim.rig.presets import PRESET_COLOUR_CAMERAS
from dotsim.shards.writer import export_webdataset
from generator.config import ConfigError, config_from_dict
from generator.driver import generate
from generator.sample_scene import SceneResources, sample_scene_spec

pytest.importorskip("bpy")

SCALE = 0.1


def rgb_config(rgb: bool = True):
    """The tiny config on a RealSense D415 (128 x 72 IR, 192 x 108 colour) with one lamp, rgb on or off."""
    data = read_toml(config_path("tiny"))
    data["rig"] = {"preset": "realsense_d415", "scale": SCALE}
    data["render"]["rgb"] = rgb
    data["lighting"]["extra_lights"] = [1, 1]
    return config_from_dict(data, "rgb test")


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    out = tmp_path_factory.mktemp("rgb") / "data"
    generate(rgb_config(), out, "train", 1, seed=3, progress=False)
    return out


def test_scene_json_records_the_colour_camera_and_the_frame_its_image(data):
    scene = dataset.read_scene(data / "shard_00000" / "scene_0000000")
    meta = scene.meta
    colour = PRESET_COLOUR_CAMERAS["realsense_d415"].scaled(SCALE)
    assert meta["format_version"] == "2.3" and meta["colour_camera"] == colour.to_dict()
    assert (colour.intrinsics.width, colour.intrinsics.height) == (192, 108)  # 1920 x 1080 at 0.1
    assert set(meta["channels"]) == set(rendered_channels(False, ("rgb",)))
    assert meta["channels"]["rgb"] == "float16"
    opaque = [o for o in meta["objects"] if o["material"].get("kind", "opaque") == "opaque"]
    assert opaque and all(len(o["material"]["tint"]) == 3 for o in opaque)
    for frame in scene.frames:
        assert frame["ir"].shape == (72, 128) and frame["rgb"].shape == (108, 192, 3)
        assert frame["rgb"].dtype == np.float16 and np.isfinite(frame["rgb"]).all()
        assert frame["rgb"].astype(np.float32).mean() > 0  # the scene's lamp lights it
    exr = OpenEXR.File(str(data / "shard_00000" / "scene_0000000" / "frame_0.exr"), separate_channels=True)
    assert [part.name() for part in exr.parts] == ["ir", "colour"]
    assert sorted(exr.parts[1].channels) == ["rgb.B", "rgb.G", "rgb.R"]


def test_the_export_the_frame_source_show_and_view_carry_it(data, tmp_path):
    folder = open_source(data, "train")
    assert "rgb" in folder.channels
    assert folder.colour_camera == PRESET_COLOUR_CAMERAS["realsense_d415"].scaled(SCALE)
    export = open_source(export_webdataset(data, tmp_path / "wds").out, "train")
    assert export.colour_camera == folder.colour_camera
    for a, b in zip(folder.frames, export.frames, strict=True):
        want, got = a.read(("rgb", "ir")), b.read(("rgb", "ir"))
        np.testing.assert_array_equal(got["rgb"], want["rgb"])
        np.testing.assert_array_equal(got["ir"], want["ir"])

    frames = dataset.read_scene(data / "shard_00000" / "scene_0000000").frames
    sheet, layout = contact_sheet(frames, "rgb", tile_width=192)
    x, y, w, h = layout.tiles[(0, "rgb")]
    # the IR tile is 192 x 108 as the colour image: the tile is the image itself, sRGB-encoded
    np.testing.assert_array_equal(sheet[y:y + h, x:x + w], colour_image(frames[0]["rgb"]))

    pytest.importorskip("rerun")
    from commands.view import view

    sizes = view(data, save=tmp_path / "scene.rrd")
    assert sizes["world/colour_camera/rgb"] == 108 * 192
    shown = subprocess.run([sys.executable, "-m", "commands.cli", "show", str(data), "-o",
                            str(tmp_path / "sheet.png")], capture_output=True, text=True)
    assert shown.returncode == 0, shown.stderr


def test_a_rig_without_a_colour_camera_is_refused_in_one_line():
    with pytest.raises(ConfigError, match=r"\[render\] rgb = true with \[rig\] preset = 'structure_core', "
                                          r"which has no colour camera; allowed: presets kinect_v1"):
        config_from_dict({"render": {"rgb": True}})


def test_without_rgb_no_draw_changes_and_frames_stay_single_part(tmp_path):
    """rgb draws the surfaces' tints from a stream of its own: every other value of the spec is that of
    the same config without it; a frame without the colour camera is a single-part file."""
    resources = SceneResources(pattern_path="p.png", pattern_sha256="0" * 64)
    on = sample_scene_spec(rgb_config(), 0, 3, "train", resources)
    off = sample_scene_spec(rgb_config(rgb=False), 0, 3, "train", resources)
    untinted = tuple(replace(o, material=replace(o.material, tint=None)) for o in on.objects)
    assert untinted == off.objects and on.poses[1].tolist() == off.poses[1].tolist()
    assert on.colour_camera is not None and off.colour_camera is None
    data = dataset.encode_frame({"ir": np.zeros((4, 6), np.float16)}, (4, 6), channels=("ir",))
    (tmp_path / "f.exr").write_bytes(data)
    assert len(OpenEXR.File(str(tmp_path / "f.exr")).parts) == 1
