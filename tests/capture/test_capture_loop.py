"""The loop of docs/CAPTURE.md end to end at tiny size, every step through the `dotsim` command line:
record wall frames and scene frames from a sensor (a pyrealsense2 software_device playing frames
of a "true" sensor: Structure Core at 0.1 scale with a known pattern) -> `capture info` ->
`capture pattern` -> `generate` with that rig and pattern -> `train` a few steps -> `infer` on the
recorded frames.

What is checked at each step is what the step promises and can be computed independently: the
extracted pattern's dots sit where the true pattern's dots do (traced through both rigs), the
generated dataset uses the device's rig and the extracted pattern, and inference gives a depth map
of the camera's size for every recorded frame.
"""

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from capture.devices import device_rig_file
from capture.record import record
from commands.cli import main
from dotsim import dataset
from dotsim.oracle import expected_pattern_image
from dotsim.patterns import detect_dots, generate_dot_pattern, load_pattern
from dotsim.rig.presets import get_preset
from generator.config import load_config
from generator.driver import generate

pytest.importorskip("pyrealsense2")
from capture.devices.realsense import RealSenseDevice  # noqa: E402
from tests.capture.realsense_software import SoftwareStereoModule, depth_z16  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
TRUE_RIG = get_preset("structure_core").scaled(0.1)  # camera 122 x 90, projector 307 x 307
WALL = 1.0  # metres


def as_uint8(image):
    return np.round(np.clip(np.nan_to_num(np.asarray(image, np.float32)), 0, 1) * 255).astype(np.uint8)


def record_from(poses, out, scenes, frames):
    with SoftwareStereoModule(TRUE_RIG, poses) as module:
        device = RealSenseDevice(module.device)
        rig, rig_file = device_rig_file(device)
        summary = record(device, rig, out, scenes=scenes, frames_per_scene=frames, progress=False)
        device.close()
    assert summary["stopped"] is None
    return rig, rig_file


def test_record_pattern_generate_train_infer(tmp_path):
    # the true sensor: a pattern whose dots the 2x coarser camera resolves (as docs/CAPTURE.md asks)
    truth = generate_dot_pattern(TRUE_RIG.projector.width, TRUE_RIG.projector.height, density=0.006,
                                 min_spacing=8.0, dot_sigma=1.6, seed=3)
    truth.save_png(tmp_path / "true_pattern.png")
    # scene frames: dotsim renders what the true sensor sees
    true_config = (ROOT / "dotsim" / "configs" / "tiny.toml").read_text().replace(
        'source = "procedural"', 'source = "file"\npath = "true_pattern.png"')
    (tmp_path / "true.toml").write_text(true_config)
    generate(load_config(tmp_path / "true.toml"), tmp_path / "world", "test", 1, seed=9, progress=False)
    scene_poses = [(as_uint8(f["ir"]), as_uint8(f["ambient"]), depth_z16(f["depth"]))
                   for ref in dataset.open_dataset(tmp_path / "world").scenes
                   for f in dataset.read_scene(ref.path).frames]
    # wall frames: a flat wall at 1 m, dots by the numpy oracle, a dim room light
    depth = np.full((TRUE_RIG.camera.height, TRUE_RIG.camera.width), WALL)
    dots = expected_pattern_image(depth, TRUE_RIG, truth.image)
    on, off = as_uint8(0.8 * dots / dots.max() + 0.1), as_uint8(np.full_like(dots, 0.1))
    wall_poses = [(on, off, depth_z16(depth))] * 3

    # 1. record, as `dotsim capture record` does, and the device's rig file (`capture info`)
    rig, rig_file = record_from(wall_poses, tmp_path / "wall", scenes=1, frames=3)
    (tmp_path / "sensor.json").write_bytes(rig_file)
    record_from(scene_poses, tmp_path / "recorded", scenes=1, frames=4)

    # 2. the pattern from the recorded wall
    assert main(["capture", "pattern", "--wall", str(tmp_path / "wall"), "--off", str(tmp_path / "wall"),
                 "--distance", str(WALL), "--rig", str(tmp_path / "sensor.json"),
                 "-o", str(tmp_path / "pattern.png")]) == 0
    pattern = load_pattern(tmp_path / "pattern.png",
                           expected_shape=(rig.projector.height, rig.projector.width))
    # the device rig's projector is centred on the true one's axis with the same focal length, so
    # a true dot at x lands at x - (true cx - device cx) in the extracted pattern
    shift = np.array([TRUE_RIG.projector.cx - rig.projector.cx, TRUE_RIG.projector.cy - rig.projector.cy])
    found = detect_dots(pattern.image)
    true_centres = truth.centres - shift
    distances = np.min(np.linalg.norm(found[:, None] - true_centres[None], axis=-1), axis=1)
    assert len(found) > 100 and np.median(distances) < 0.5

    # 3. generate with the device's rig and the extracted pattern
    config = (ROOT / "dotsim" / "configs" / "tiny.toml").read_text()
    config = config.replace('preset = "structure_core"\nscale = 0.1', 'file = "sensor.json"')
    config = config.replace('source = "procedural"', 'source = "file"\npath = "pattern.png"')
    (tmp_path / "sensor.toml").write_text(config)
    assert main(["generate", "--config", str(tmp_path / "sensor.toml"), "--out", str(tmp_path / "synthetic"),
                 "--split", "train", "--scenes", "2", "--seed", "1", "--no-progress"]) == 0
    scene = dataset.read_scene(dataset.open_dataset(tmp_path / "synthetic").scenes[0].path)
    assert scene.meta["rig"] == rig.to_dict()
    assert scene.meta["pattern"]["sha256"] == pattern.sha256

    # 4. train a few steps
    train = tomllib.loads((ROOT / "dotsim" / "configs" / "train_tiny.toml").read_text())
    train["model"]["lines"] = rig.camera.height // 2
    train["data"].update(crop_width=64, crop_height=48)
    train["train"].update(max_steps=3, batch_size=2, checkpoint_every=1000, image_every=1000)
    (tmp_path / "train.toml").write_text(to_toml(train))
    assert main(["train", "--config", str(tmp_path / "train.toml"), "--data", str(tmp_path / "synthetic"),
                 "--out", str(tmp_path / "run")]) == 0

    # 5. infer on the recorded frames
    recorded = sorted((tmp_path / "recorded").glob("shard_*/scene_*/frame_*.exr"))
    assert len(recorded) == 4
    assert main(["infer", "--checkpoint", str(tmp_path / "run" / "checkpoint.pt"), "--out",
                 str(tmp_path / "inferred"), *map(str, recorded)]) == 0
    outputs = sorted((tmp_path / "inferred").glob("*.exr"))
    assert len(outputs) == 4
    import OpenEXR

    for path in outputs:
        channels = OpenEXR.File(str(path), separate_channels=True).channels()
        assert channels["depth"].pixels.shape == (rig.camera.height, rig.camera.width)
        assert np.isfinite(channels["depth"].pixels).mean() > 0.5
    assert json.loads((tmp_path / "sensor.json").read_text())["device"]["has_depth"] is True


def to_toml(tables: dict) -> str:
    """The few TOML forms a trainer config uses: top-level scalars, tables of scalars and lists."""
    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(v)

    lines = [f"{k} = {value(v)}" for k, v in tables.items() if not isinstance(v, dict)]
    for name, table in tables.items():
        if isinstance(table, dict):
            lines += ["", f"[{name}]"] + [f"{k} = {value(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"
