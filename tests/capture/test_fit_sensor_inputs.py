"""`dotsim capture fit-sensor` on recordings as they come: frames of a still scene through dotsim's
sensor model with a known read and shot noise, written as a sensor's SDK writes them (10-bit data in
16-bit PNGs), then clipped, all black, given a wrong --white-level or none, and imported as datasets.

The truth is the sensor model's read and shot noise; clipping leaves them where they are (the clipped
samples are left out), so the fit must still find them within 10%.
"""

import shutil
import tomllib
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy import ndimage

from capture.sensor_fit import measure, noise_without_spatial_bias
from capture.static_recording import StaticRecording, StaticScene
from commands.cli import main
from dotsim.sensor.model import SensorModel
from dotsim.sensor.settings import SensorSpec
from generator.config import config_from_dict

READ, SHOT = 0.004, 0.03
WIDTH, HEIGHT = 243, 179  # structure_core at [rig] scale 0.2, so `capture import --scale 0.2` takes them
FRAMES = 8
DOTS = 150


def still_scene(seed: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(projector-on frames, projector-off frames, the light without noise) of a still scene: a
    ramp of ambient light from dark to bright and 700 sparse dots, through the sensor model (10 bits)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH]
    ambient = 0.03 + 0.6 * x / WIDTH + 0.0003 * y
    dots = np.zeros_like(ambient)
    for cx, cy in rng.uniform(4, [WIDTH - 4, HEIGHT - 4], (DOTS, 2)):
        dots += 0.3 * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * 1.0**2))
    model = SensorModel(SensorSpec(exposure="fixed", gain=1.0, bloom_strength=0.0, blur_sigma=0.0,
                                   read_noise=READ, shot_noise=SHOT, bit_depth=10))
    on = np.stack([model.apply(ambient + dots, rng) for _ in range(FRAMES)]).astype(np.float64)
    off = np.stack([model.apply(ambient, rng) for _ in range(FRAMES)]).astype(np.float64)
    return on, off, ambient + dots


def write_raw(folder: Path, frames: np.ndarray, clip: int = 1023, prefix: str = "on") -> Path:
    """Frames as 16-bit PNGs of 10-bit raw values, clipped at `clip` (a sensor saturating there)."""
    folder.mkdir(parents=True, exist_ok=True)
    for k, frame in enumerate(frames):
        raw = np.minimum(np.round(frame * 1023), clip).astype(np.uint16)
        cv2.imwrite(str(folder / f"{prefix}_{k}.png"), raw)
    return folder


def fit_sensor(capsys, *args) -> tuple[int, str, str]:
    status = main(["capture", "fit-sensor", *map(str, args)])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def table(path: Path) -> dict:
    return tomllib.loads(path.read_text())["sensor"]


@pytest.fixture(scope="module")
def scene():
    return still_scene()


def test_clipped_samples_are_left_out_and_counted(scene, tmp_path, capsys):
    on, off, _ = scene
    raw = np.round(on * 1023)
    clip = int(np.percentile(raw, 95))  # 5% of the samples at or above it
    folder = write_raw(tmp_path / "clipped", on, clip)
    share = np.mean(np.minimum(raw, clip) >= clip)
    status, out, err = fit_sensor(capsys, folder, "--white-level", 1023, "-o", tmp_path / "s.toml")
    assert status == 0, err
    fitted = table(tmp_path / "s.toml")
    assert fitted["read_noise"] == pytest.approx(READ, rel=0.1)
    assert fitted["shot_noise"] == pytest.approx(SHOT, rel=0.1)
    count = int(np.sum(np.minimum(raw, clip) >= clip))
    assert f"note: clipped: {count} of {on.size} projector-on samples ({100 * share:.2f}%) at or above the " \
           f"saturation level {clip / 1023:.4g}, left out of every statistic" in out
    # clipped so low that too little is left: refused, saying what was left out
    low = int(np.percentile(raw, 15))
    write_raw(tmp_path / "mostly_clipped", on, low)
    status, _, err = fit_sensor(capsys, tmp_path / "mostly_clipped", "--white-level", 1023,
                                "-o", tmp_path / "low.toml")
    assert status == 2 and err.count("\n") == 1
    assert "; clipped: " in err and "left out of every statistic" in err
    assert not (tmp_path / "low.toml").exists()


def test_no_signal_white_level_and_low_bits(scene, tmp_path, capsys):
    on, _, _ = scene
    black = tmp_path / "black"
    black.mkdir()
    for k in range(4):
        cv2.imwrite(str(black / f"f{k}.png"), np.zeros((HEIGHT, WIDTH), np.uint16))
    output = tmp_path / "s.toml"
    status, _, err = fit_sensor(capsys, black, "--white-level", 1023, "-o", output)
    assert status == 2 and "no signal: every projector-on sample is 0" in err and "saturat" not in err
    folder = write_raw(tmp_path / "ten_bit", on)
    highest = int(np.round(on * 1023).max())
    status, _, err = fit_sensor(capsys, folder, "--white-level", 255, "-o", output)
    assert status == 2 and f"--white-level 255: below the data's maximum {highest}" in err
    status, _, err = fit_sensor(capsys, folder, "-o", output)
    assert status == 2 and f"16-bit files whose values reach only {highest}: 10-bit data in the low bits " \
                           "of a 16-bit file? pass --white-level 1023" in err
    assert not output.exists()


def test_dataset_folders_are_datasets(scene, tmp_path, capsys):
    on, off, _ = scene
    write_raw(tmp_path / "on", on)
    write_raw(tmp_path / "off", off, prefix="off")
    data = tmp_path / "data"
    assert main(["capture", "import", "--on", str(tmp_path / "on"), "--off", str(tmp_path / "off"),
                 "--rig", "structure_core", "--scale", "0.2", "--white-level", "1023",
                 "--frames-per-scene", str(FRAMES), "--out", str(data)]) == 0
    capsys.readouterr()
    output = tmp_path / "s.toml"
    status, out, err = fit_sensor(capsys, data, "-o", output)
    assert status == 0, err
    assert "(capture; 1 scene(s), 8 projector-on frame(s), 243 x 179 px)" in out
    assert table(output)["read_noise"] == pytest.approx(READ, rel=0.1)
    assert table(output)["shot_noise"] == pytest.approx(SHOT, rel=0.1)
    # its projector-off frames give the [lighting] ambient_ratio of its one scene, which pastes into a config
    ambient = float(out.split("ambient / projector light")[1].split()[0])
    lighting = tomllib.loads(output.read_text())["lighting"]
    assert lighting["ambient_ratio"] == [pytest.approx(ambient, rel=0.01)] * 2
    assert config_from_dict({"lighting": lighting}).lighting.ambient_ratio == tuple(lighting["ambient_ratio"])
    # the ambient over the dots' light: the ramp's mean over the dots' where they are (the dots cover a
    # few px each, so it lies between the whole frame's ratio and that at the dots' peaks)
    on_light = scene[2]
    assert 0.357 / 0.3 < ambient < float(on_light.mean() - 0.357) ** -1 * 0.357
    output.unlink()
    other = tmp_path / "other"
    shutil.copytree(data, other)
    shard = next(p for p in data.iterdir() if p.name.startswith("shard_"))
    scene_folder = next(p for p in shard.iterdir() if p.name.startswith("scene_"))
    unsealed = tmp_path / "unsealed"
    shutil.copytree(data, unsealed)
    (unsealed / "index.json").unlink()
    refused = {
        (data, other): f"RECORDING {data}: a dataset, read as its still scenes: give it alone",
        (data, tmp_path / "on"): f"RECORDING {data}: a dataset, read as its still scenes: give it alone",
        (shard,): f"RECORDING {shard}: a shard of a dataset, not a folder of frames",
        (scene_folder,): f"RECORDING {scene_folder}: a scene of a dataset, not a folder of frames",
        (unsealed,): f"RECORDING {unsealed}: a dataset without its index.json",
    }
    for recording, message in refused.items():
        status, _, err = fit_sensor(capsys, *recording, "-o", output)
        assert status == 2 and message in err and err.count("\n") == 1, err
        assert not output.exists()
    status, _, err = fit_sensor(capsys, tmp_path / "on", "--off", data, "--white-level", 1023, "-o", output)
    assert status == 2 and f"--off {data}: a dataset" in err


def textured_scene(seed: int, width: int = 480, height: int = 360) -> np.ndarray:
    """The light of a textured still scene without noise: a ramp of ambient light from dark to bright on
    a surface whose reflectance varies by 5% from pixel to pixel (fine texture, which one frame cannot
    tell from noise), and 1500 dots."""
    rng = np.random.default_rng(seed)
    x = np.arange(width)[None, :]
    texture = ndimage.gaussian_filter(rng.standard_normal((height, width)), 0.7)
    impulses = np.zeros((height, width))
    impulses[rng.integers(4, height - 4, 1500), rng.integers(4, width - 4, 1500)] = 0.25 * 2 * np.pi * 0.9**2
    return (0.04 + 0.5 * x / width) * (1 + 0.05 * texture / texture.std()) + \
        ndimage.gaussian_filter(impulses, 0.9)  # dots 0.25 high, sigma 0.9 px


def test_one_frame_noise_corrected_on_a_rendering_of_known_noise():
    """One frame of a textured scene: the spatial estimate counts the texture as noise (the shot noise
    reads 25% or more high); noise_without_spatial_bias, calibrated on four still frames of another
    scene of the same kind with another known noise (as --compare's rendering), gives the shot noise
    within 10%, without knowing the recording's."""
    model = SensorModel(SensorSpec(exposure="fixed", gain=1.0, bloom_strength=0.0, blur_sigma=0.0,
                                   read_noise=READ, shot_noise=SHOT, bit_depth=10))
    rendering_model = SensorModel(replace(model.settings, read_noise=0.003, shot_noise=0.02))
    rng = np.random.default_rng(4)
    one = model.apply(textured_scene(1), rng).astype(np.float64)[None]
    four = np.stack([rendering_model.apply(textured_scene(2), rng) for _ in range(4)]).astype(np.float64)

    def recording(name: str, frames: np.ndarray) -> StaticRecording:
        return StaticRecording(name, "images", frames.shape[:0:-1], (len(frames),), 1e-9, 1.0, None,
                               lambda: iter([StaticScene(name, frames)]))

    stats, reference = measure(recording("one", one)), measure(recording("rendering", four))
    assert stats.method == "spatial" and reference.method == "temporal"
    assert reference.shot_noise.value == pytest.approx(0.02, rel=0.02)
    assert stats.shot_noise.value > 1.25 * SHOT
    _, shot, note = noise_without_spatial_bias(stats.read_noise, stats.shot_noise, reference)
    assert shot.value == pytest.approx(SHOT, rel=0.1) and "bias taken out" in note
