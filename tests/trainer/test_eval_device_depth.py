"""`dotsim eval` on frames that store the device's own depth: a row 'device' of its own ("the device's own
depth", trainer.scoring.DeviceDepthMethod), recounted here from the planes' true depth. The frames are a D415
pair before planes (tests/trainer_fixtures.py's oracle) whose device_depth is the stereo engine's
(dotsim.device_depth) on their left and right IR, as the post-render makes it."""

from __future__ import annotations

import dataclasses
import doctest

import numpy as np

from dotsim.channels import rendered_channels
from dotsim.dataset import pattern_path, seal_dataset, write_scene
from dotsim.device_depth import DeviceDepthConfig, as_channel, stereo_depth
from dotsim.frame_source import open_source
from dotsim.oracle_dataset import TINY_SCALE, pair_frame, planar_depth
from dotsim.patterns import generate_dot_pattern
from dotsim.rig.presets import get_preset
from tests.trainer_fixtures import tiny_config
from trainer import device_depth_row
from trainer.evaluate import evaluate, row_of
from trainer.train import train

ENGINE = DeviceDepthConfig(engine="stereo", num_disparities=128)


def device_dataset(root, scenes: int, test_scenes: int):
    rig = get_preset("realsense_d415").scaled(TINY_SCALE)  # 128 x 72
    dots = generate_dot_pattern(rig.projector.width, rig.projector.height, seed=0)
    root.mkdir(parents=True)
    dots.save_png(pattern_path(root))
    for k in range(scenes + test_scenes):
        rng = np.random.default_rng([0, k])
        frames = []
        for _ in range(2):
            frame = pair_frame(planar_depth(rig, rng.uniform(0.6, 1.5), 0.0, rng.uniform(-0.3, 0.3)), rig,
                               np.asarray(dots.image, np.float64), rng, 0.01, 10)
            depth = stereo_depth(frame["ir"].astype(np.float32), frame["ir_right"].astype(np.float32),
                                 rig.camera.fx, rig.second_camera_translation[0], ENGINE, TINY_SCALE)
            frames.append(frame | {"device_depth": as_channel(depth)})
        meta = {"split": "train" if k < scenes else "test", "seed": 0, "rig": rig.to_dict(),
                "pattern": {"source": dots.source, "sha256": dots.sha256, "width": rig.projector.width,
                            "height": rig.projector.height, "params": dots.params},
                "poses": [np.eye(4).tolist()] * 2, "render": {"kind": "oracle (tests/trainer_fixtures.py)"}}
        write_scene(root, k, meta, frames, scenes_per_shard=3,
                    channels=rendered_channels(True, ("device_depth",)))
    seal_dataset(root)
    return root


def test_eval_scores_the_devices_own_depth_as_a_row(tmp_path):
    data = device_dataset(tmp_path / "data", 2, 2)
    cfg = tiny_config(2)
    cfg = dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, lines=36))
    train(cfg, open_source(data, "train"), tmp_path / "run", progress=False)
    rows = evaluate(tmp_path / "run" / "checkpoint.pt", open_source(data, "test"), tmp_path / "eval",
                    images=0, progress=False)
    device = row_of(rows, "device", "all")
    assert device is not None and row_of(rows, "device", "0-1") is not None
    assert "device: the device's own depth" in (tmp_path / "eval" / "eval.md").read_text()
    # by hand: the device's depth as the projector's disparity fx B_p / z against the true depth's, a
    # pixel without a reading an outlier
    source = open_source(data, "test")
    frames, rig = source.frames, source.rig
    fx_b = rig.camera.fx * rig.projector_translation[0]
    over = total = none = 0
    for ref in frames:
        f = ref.read(("device_depth", "depth", "visibility"))
        valid = f["visibility"] > 0
        error = np.abs(fx_b / f["device_depth"].astype(np.float64) - fx_b / f["depth"].astype(np.float64))
        over += int(np.sum(~(error[valid] <= 0.5)))
        none += int(np.sum(np.isnan(f["device_depth"][valid])))
        total += int(valid.sum())
    assert device["pixels"] == total and abs(device["o(0.5)"] - over / total) < 1e-9
    assert 0 < none < over + 1  # the left band and other holes count as outliers


def test_doctests():
    result = doctest.testmod(device_depth_row)
    assert result.attempted >= 3 and result.failed == 0
