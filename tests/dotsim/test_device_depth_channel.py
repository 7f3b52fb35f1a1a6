"""A rendered frame's `device_depth` (the simulated device's depth, [device_depth] on) through the
dataset: written and read back bit for bit with its holes as NaN, exported to shards and read from them
(dotsim.frame_source), listed in scene.json's channels."""

from __future__ import annotations

import numpy as np

from dotsim import dataset as ds
from dotsim.channels import rendered_channels
from dotsim.frame_source import open_source
from dotsim.oracle_dataset import TINY_SCALE, random_depth, synthetic_frame
from dotsim.patterns import generate_dot_pattern
from dotsim.rig.presets import get_preset
from dotsim.shards.writer import export_webdataset


def test_device_depth_round_trips_through_the_folder_and_the_shards(tmp_path):
    rig = get_preset("structure_core").scaled(TINY_SCALE)
    dots = generate_dot_pattern(rig.projector.width, rig.projector.height, seed=0)
    root = tmp_path / "data"
    root.mkdir()
    dots.save_png(ds.pattern_path(root))
    rng = np.random.default_rng(3)
    frames = []
    for _ in range(2):
        frame = synthetic_frame(random_depth(rig, rng), rig, dots.image.astype(np.float64), rng, ir_bits=10)
        device = np.round(frame["depth"] * 1000) / 1000  # millimetre steps, as a device reports
        device[:, :12] = np.nan  # the left band without depth
        device[rng.uniform(size=device.shape) < 0.1] = np.nan
        frames.append(frame | {"device_depth": device.astype(np.float32)})
    meta = {"split": "train", "seed": 0, "rig": rig.to_dict(), "poses": [np.eye(4).tolist()] * 2,
            "pattern": {"source": dots.source, "sha256": dots.sha256, "width": rig.projector.width,
                        "height": rig.projector.height, "params": dots.params},
            "render": {"kind": "oracle (tests/trainer_fixtures.py)"}}
    channels = rendered_channels(False, ("device_depth",))
    scene = ds.write_scene(root, 0, meta, frames, channels=channels)
    ds.seal_dataset(root)
    assert "device_depth" in ds.read_scene_meta(scene)["channels"]
    read = ds.read_scene(scene).frames
    for frame, back in zip(frames, read, strict=True):
        assert back["device_depth"].dtype == np.float32
        np.testing.assert_array_equal(back["device_depth"], frame["device_depth"])  # NaN where none
    shards = export_webdataset(root, tmp_path / "shards")
    exported = open_source(shards.out, "all")
    assert "device_depth" in exported.channels
    for ref, back in zip(exported.frames, read, strict=True):
        np.testing.assert_array_equal(ref.read(("device_depth",))["device_depth"], back["device_depth"])
