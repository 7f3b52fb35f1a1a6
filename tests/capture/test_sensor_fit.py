"""`dotsim capture fit-sensor` end to end: rendered captures of known sensors (real Cycles renders of
still scenes, many frames each with their own noise), the same frames as image files, a single
frame, a recording through the software RealSense of the capture tests, and bad recordings.

The truth is the [sensor] table the captures were rendered with; the fit must come within 10% of
each of its read noise, shot noise, blur and speckle contrast.
"""

import json
import tomllib
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from capture import still_scenes
from capture.sensor_fit import fit, measure
from capture.static_recording import open_recording
from commands.cli import main
from dotsim import dataset
from dotsim.rig.presets import get_preset
from dotsim.sensor.model import SensorModel
from dotsim.sensor.settings import SensorSpec
from generator.config import config_from_dict, load_config
from generator.driver import generate

TINY = load_config(Path(__file__).resolve().parents[2] / "dotsim" / "configs" / "tiny.toml")
SCALE = 0.2  # 243 x 179: enough isolated dots in 4 scenes
# the known sensor of capture/still_scenes.py (bench.sensor_fit's), with blur and grain in
# full-resolution px that are 1 and 2 px here
KNOWN = {**still_scenes.KNOWN, "blur_sigma": 5.0, "speckle_grain": 10.0}


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """The still scenes of capture/still_scenes.py (bench.sensor_fit's) at scale 0.2: a 'capture'
    with the KNOWN sensor and a rendering of the default sensor to compare it with."""
    return still_scenes.render_pair(TINY, tmp_path_factory.mktemp("still"), SCALE, 4, KNOWN)


def fit_sensor(capsys, *args) -> tuple[int, str, str]:
    status = main(["capture", "fit-sensor", *map(str, args)])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def test_fit_recovers_the_known_sensor_from_rendered_captures(rendered, tmp_path, capsys):
    output = tmp_path / "sensor.toml"
    status, out, _ = fit_sensor(capsys, rendered["capture"], "--compare", rendered["reference"],
                                "--speckle-grain", KNOWN["speckle_grain"], "-o", output)
    assert status == 0
    table = tomllib.loads(output.read_text())["sensor"]
    for key in ("read_noise", "shot_noise", "blur_sigma", "speckle_contrast"):
        assert table[key] == pytest.approx(KNOWN[key], rel=0.1), key
    assert table["bit_depth"] == 10 and table["speckle_grain"] == KNOWN["speckle_grain"]
    # the table pastes into a config as it is
    assert config_from_dict({"sensor": table}).sensor.read_noise == table["read_noise"]
    assert "recording" in out and "rendering" in out and "dot FWHM, px" in out
    drawing = cv2.imread(str(output.with_suffix(".png")))
    orange = np.all(drawing == (40, 150, 255), axis=2).sum()
    blue = np.all(drawing == (255, 160, 60), axis=2).sum()
    assert drawing.shape == (640, 880, 3) and orange > 500 and blue > 500


# A projector focused at 1.5 m with a 4 cm aperture (blur circles of up to 10 px here: the widths change
# by whole pixels between the rooms' near and far walls), and a camera blur of 0.5 px; no speckle, which
# narrows the dots it falls on
DEFOCUSED = {**KNOWN, "blur_sigma": 2.5, "speckle_contrast": 0.0, "projector_aperture": 0.04,
             "projector_focus": 1.5}


def test_fit_recovers_the_projectors_defocus_from_the_dots_against_depth(tmp_path):
    pair = still_scenes.render_pair(TINY, tmp_path, SCALE, 4, DEFOCUSED)
    capture, reference = (measure(open_recording([str(pair[name])])) for name in ("capture", "reference"))
    fitted = fit(capture, reference, DEFOCUSED["speckle_grain"])
    assert fitted.values["projector_aperture"] == pytest.approx(0.04, rel=0.1)
    assert fitted.values["projector_focus"] == pytest.approx(1.5, rel=0.1)
    assert fitted.values["blur_sigma"] == pytest.approx(2.5, rel=0.1)
    assert "against depth" in fitted.notes["projector_aperture"]
    # image files have no depth: the rendering's defocus is kept, and the note says why
    scene = dataset.read_scene(dataset.open_dataset(pair["capture"]).scenes[0].path)
    write_frames(scene.frames, tmp_path / "files")
    files = measure(open_recording([str(tmp_path / "files")], white_level=1023))
    kept = fit(files, reference, DEFOCUSED["speckle_grain"])
    assert kept.values["projector_aperture"] == 0.0 and "kept" in kept.notes["projector_aperture"]


def write_frames(scene_frames, folder: Path, scale: float = 1.0, clip: int = 1023,
                 channel: str = "ir") -> list[Path]:
    """Frames' `channel` as 16-bit PNGs of 10-bit raw values, as a sensor's SDK saves them, clipped at
    `clip` (a sensor that saturates there)."""
    folder.mkdir()
    paths = []
    for k, frame in enumerate(scene_frames):
        raw = np.round(frame[channel].astype(np.float64) * 1023 * scale)
        raw = np.minimum(raw, clip).astype(np.uint16)
        paths.append(folder / f"on_{k}.png")
        cv2.imwrite(str(paths[-1]), raw)
    return paths


def test_image_files_and_bad_recordings(rendered, tmp_path, capsys):
    scenes = [dataset.read_scene(ref.path) for ref in dataset.open_dataset(rendered["capture"]).scenes]
    still = write_frames(scenes[0].frames, tmp_path / "still")
    output = tmp_path / "sensor.toml"
    status, out, _ = fit_sensor(capsys, tmp_path / "still", "--white-level", 1023, "-o", output)
    assert status == 0 and "(images; 1 scene(s), 4 projector-on frame(s)" in out
    table = tomllib.loads(output.read_text())["sensor"]
    assert table["read_noise"] == pytest.approx(KNOWN["read_noise"], rel=0.1)
    assert table["shot_noise"] == pytest.approx(KNOWN["shot_noise"], rel=0.1)
    assert table["bit_depth"] == 10 and "blur_sigma" not in table
    write_frames(scenes[0].frames[:2] + scenes[1].frames[:2], tmp_path / "moving")
    write_frames(scenes[0].frames, tmp_path / "saturated", scale=10.0)
    bad = {
        "too few frames: 3 projector-on frame(s) of a static scene; allowed: 1 (statistics of flat "
        "regions of one frame) or at least 4": [str(p) for p in still[:3]],
        "moving scene: ": [str(tmp_path / "moving")],
    }
    output.unlink()
    output.with_suffix(".png").unlink()
    for message, recording in bad.items():
        status, _, err = fit_sensor(capsys, *recording, "--white-level", 1023, "-o", output)
        assert status == 2 and message in err and err.count("\n") == 1, err
        assert not output.exists() and not output.with_suffix(".png").exists()
    missing = tmp_path / "no" / "sensor.toml"
    status, _, err = fit_sensor(capsys, tmp_path / "still", "-o", missing)
    assert status == 2
    assert err == f"dotsim capture fit-sensor: error: -o {missing}: folder {missing.parent} does not exist\n"
    # 10 times as bright, the brightest samples clipped at full scale: they are left out, and the noise
    # of what is left is the known one scaled (read noise 10 x, shot noise sqrt(10) x)
    status, out, err = fit_sensor(capsys, tmp_path / "saturated", "--white-level", 1023, "-o", output)
    assert status == 0 and "note: clipped: " in out, err
    table = tomllib.loads(output.read_text())["sensor"]
    assert table["read_noise"] == pytest.approx(10 * KNOWN["read_noise"], rel=0.1)
    assert table["shot_noise"] == pytest.approx(10**0.5 * KNOWN["shot_noise"], rel=0.1)
    # a rendering whose scenes move between frames (tiny.toml's motion) is no still recording
    generate(TINY, tmp_path / "moving_rendering", "train", 1, seed=0, progress=False)
    status, _, err = fit_sensor(capsys, tmp_path / "moving_rendering", "-o", output)
    assert status == 2 and err.endswith("its frames have different poses: not a static scene; render one "
                                        "with [motion] translation = 0 and rotation = 0 in the config\n")


def test_one_frame_falls_back_to_flat_regions_and_says_so(tmp_path, capsys):
    """One frame of a scene with flat patches and sparse dots, through the sensor model."""
    y, x = np.mgrid[0:360, 0:480]
    scene = 0.05 + 0.1 * (x // 60) + 0.0002 * y
    rng = np.random.default_rng(5)
    for cx, cy in rng.uniform(10, [470, 350], (300, 2)):
        scene += 0.3 * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * 1.1**2))
    model = SensorModel(SensorSpec(exposure="fixed", gain=1.0, bloom_strength=0.0, blur_sigma=0.0,
                                       read_noise=0.005, shot_noise=0.025, bit_depth=12))
    frame = np.round(model.apply(scene, rng).astype(np.float64) * 4095).astype(np.uint16)
    cv2.imwrite(str(tmp_path / "one.png"), frame)
    status, out, _ = fit_sensor(capsys, tmp_path / "one.png", "--white-level", 4095,
                                "-o", tmp_path / "s.toml")
    assert status == 0 and "note: one frame per scene: noise from flat regions of single frames" in out
    table = tomllib.loads((tmp_path / "s.toml").read_text())["sensor"]
    assert table["read_noise"] == pytest.approx(0.005, rel=0.15)
    assert table["shot_noise"] == pytest.approx(0.025, rel=0.1)
    assert table["bit_depth"] == 12
    # the same scene without its dots: nothing to measure them on
    flat = model.apply(0.05 + 0.1 * (x // 60) + 0.0002 * y, rng).astype(np.float64)
    cv2.imwrite(str(tmp_path / "flat.png"), np.round(flat * 4095).astype(np.uint16))
    status, _, err = fit_sensor(capsys, tmp_path / "flat.png", "--white-level", 4095,
                                "-o", tmp_path / "f.toml")
    assert status == 2 and "isolated dot(s) on flat regions; allowed: 10 or more" in err


def test_a_recording_of_the_software_realsense(tmp_path, capsys):
    """Still scenes rendered with a known sensor (fixed exposure, an extra light for the ambient),
    their projector-off frames the same sensor on the ambient light, played by the software D400 of
    the capture tests (8-bit IR), recorded by `capture record`'s recorder and fitted."""
    pytest.importorskip("pyrealsense2")
    from capture.devices.realsense import RealSenseDevice
    from capture.record import record
    from tests.capture.realsense_software import SoftwareStereoModule, depth_z16

    sensor = {"exposure": "fixed", "gain": 1.0, "read_noise": 0.01, "shot_noise": 0.04, "blur_sigma": 5.0}
    config = still_scenes.still_config(TINY, SCALE, sensor, lighting={"extra_lights": [1, 1],
                                                               "light_power": [3.0, 6.0]})
    generate(config, tmp_path / "rendered", "train", 2, seed=2, progress=False)
    model, rng = SensorModel(config.sensor.at_scale(config.rig.scale)), np.random.default_rng(6)
    to_uint8 = lambda image: np.round(np.clip(image, 0, 1) * 255).astype(np.uint8)  # noqa: E731
    poses = []
    for ref in dataset.open_dataset(tmp_path / "rendered").scenes:
        for frame in dataset.read_scene(ref.path).frames:
            off = model.apply(frame["ambient"].astype(np.float64), rng)
            poses.append((to_uint8(frame["ir"].astype(np.float64)), to_uint8(off), depth_z16(frame["depth"])))
    rig = get_preset("structure_core").scaled(SCALE)
    with SoftwareStereoModule(rig, poses) as module:
        device = RealSenseDevice(module.device)
        summary = record(device, device.rig(), tmp_path / "rec", scenes=2, frames_per_scene=4, progress=False,
                         preview=False)
        device.close()
    assert summary["stopped"] is None and summary["frames"] == 8
    status, out, _ = fit_sensor(capsys, tmp_path / "rec", "-o", tmp_path / "device.toml")
    assert status == 0 and "(capture; 2 scene(s), 8 projector-on frame(s), 243 x 179 px)" in out
    table = tomllib.loads((tmp_path / "device.toml").read_text())["sensor"]
    assert table["bit_depth"] == 8
    assert table["read_noise"] == pytest.approx(0.01, rel=0.15)
    assert table["shot_noise"] == pytest.approx(0.04, rel=0.15)
    assert "ambient / projector light" in out and "dots per 1000 px, " in out  # off frames, device depth


def test_rendered_captures_with_5_percent_clipped(rendered):
    """The rendered capture's 4 still scenes made brighter (a higher gain: every 10-bit value times g)
    until 5% of their samples clip at full scale: the clipped samples are left out, and the noise of
    the rest is the known one at that gain (read noise g x, shot noise sqrt(g) x: the variance is
    g^2 (r^2 + k^2 L / g) at the new level L)."""
    recording = open_recording([str(rendered["capture"])])
    raw = np.concatenate([np.round(scene.on * 1023) for scene in recording.scenes()])
    gain = 1023 / np.percentile(raw, 95)
    count = int(np.sum(np.round(raw * gain) >= 1023))
    assert 0.045 < count / raw.size < 0.055

    def clipped():
        for scene in recording.scenes():
            yield replace(scene, on=np.minimum(np.round(scene.on * 1023 * gain), 1023) / 1023)

    stats = measure(replace(recording, read=clipped))
    assert stats.saturation == 1.0 and stats.saturated == count
    fitted = fit(stats).values
    assert fitted["read_noise"] == pytest.approx(gain * KNOWN["read_noise"], rel=0.1)
    assert fitted["shot_noise"] == pytest.approx(gain**0.5 * KNOWN["shot_noise"], rel=0.1)


def test_compare_checks_the_camera(rendered, tmp_path, capsys):
    """--compare: a rendering of another camera is refused (field of view from the rigs of two
    datasets, aspect ratio against image files); image files say only the aspect was checked."""
    scenes = [dataset.read_scene(ref.path) for ref in dataset.open_dataset(rendered["capture"]).scenes]
    write_frames(scenes[0].frames, tmp_path / "on")
    output = tmp_path / "sensor.toml"
    status, out, err = fit_sensor(capsys, tmp_path / "on", "--white-level", 1023, "--compare",
                                  rendered["reference"], "-o", output)
    assert status == 0, err
    assert "note: the recording's rig is not known (image files): only the rendering's aspect ratio" in out
    square = tmp_path / "square"
    square.mkdir()
    for path in sorted((tmp_path / "on").iterdir()):
        cv2.imwrite(str(square / path.name), cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[:, 32:211])
    output.unlink()
    status, _, err = fit_sensor(capsys, square, "--white-level", 1023, "--compare", rendered["reference"],
                                "-o", output)
    assert status == 2 and not output.exists()
    assert "243 x 179 px (aspect 1.358), the recording 179 x 179 px (aspect 1.000): another camera" in err
    # the same frames imported with a rig of another field of view (focal length 1.2 times)
    rig = get_preset("structure_core").scaled(SCALE).to_dict()
    rig["camera"] = {**rig["camera"], "fx": rig["camera"]["fx"] * 1.2, "fy": rig["camera"]["fy"] * 1.2}
    (tmp_path / "zoom.json").write_text(json.dumps({"rig": rig}))
    write_frames(scenes[0].frames, tmp_path / "off", channel="ambient")
    assert main(["capture", "import", "--on", str(tmp_path / "on"), "--off", str(tmp_path / "off"), "--rig",
                 str(tmp_path / "zoom.json"), "--white-level", "1023", "--out", str(tmp_path / "zoom")]) == 0
    capsys.readouterr()
    status, _, err = fit_sensor(capsys, tmp_path / "zoom", "--compare", rendered["reference"], "-o", output)
    assert status == 2 and "another field of view; render your config with the recording's rig" in err, err
    assert not output.exists()


def test_compare_a_recording_with_a_rendering(rendered, tmp_path, capsys):
    """`capture compare` of each of the rendered capture's scenes as image files (with its reference
    pattern as a PNG in camera pixels) against the rendered capture itself: the same frames measured
    through both paths, so every ratio is near 1, and the rendering's one-frame statistics are the means
    of the scenes' (the same mean frames); the table, the JSON and the picture are written."""
    from capture.realism import dataset_frames

    scenes = [dataset.read_scene(ref.path) for ref in dataset.open_dataset(rendered["capture"]).scenes]
    reference = dataset_frames(rendered["capture"])[1]
    cv2.imwrite(str(tmp_path / "reference.png"),
                np.round(reference / reference.max() * 65535).astype(np.uint16))
    report = tmp_path / "report.png"
    tables = []
    for k, scene in enumerate(scenes):
        write_frames(scene.frames, tmp_path / f"on{k}")
        status = main(["capture", "compare", str(tmp_path / f"on{k}"), str(rendered["capture"]),
                       "--white-level", "1023", "--pattern", str(tmp_path / "reference.png"),
                       "-o", str(report)])
        out, err = capsys.readouterr()
        assert status == 0, err
        table = json.loads(report.with_suffix(".json").read_text())["rows"]
        tables.append({row["statistic"].split(" (")[0]: row for row in table})
    rows = tables[0]
    ambient = "ambient / projector light, one frame"
    scene_ratios = [table[ambient]["recording"] for table in tables]
    # within 1%: each run's window is twice its recording's mean dot spacing, so the scenes' windows differ
    # by a few px from the first run's, in which the rendering's scenes were measured
    assert rows[ambient]["rendering"] == pytest.approx(np.mean(scene_ratios), rel=0.01)
    unmatched = [table["SGBM unmatched share"]["recording"] for table in tables]
    # within 0.1% of the pixels: the reference's two ways (the PNG's 16 bits, the float) move SGBM's
    # decision on a few pixels, and here only about 0.3% go unmatched (a ratio of 0.94 was 7 pixels)
    assert 0 < max(unmatched) < 1  # flat walls: 0-0.3% of the pixels, none in two of the scenes
    assert rows["SGBM unmatched share"]["rendering"] == pytest.approx(np.mean(unmatched), abs=1e-3)
    for name in ("read noise", "shot noise at full scale", "dot FWHM, recording px"):
        assert rows[name]["ratio"] == pytest.approx(1, abs=0.15), name
    assert "statistic" in out and "ratio" in out
    assert "SGBM unmatched share (against the reference pattern)" in out
    picture = cv2.imread(str(report))
    assert picture.shape[1] == 880 and picture.shape[0] > 640
    # a recording given as the rendering, and a picture that is not a .png: one line each, nothing written
    report.unlink()
    jpg, folder = tmp_path / "r.jpg", tmp_path / "folder.png"
    folder.mkdir()  # a folder where the picture goes (issue 45: a command writes its own files only)
    for args, message in (([str(tmp_path / "on0"), str(tmp_path / "zoom_missing")], "zoom_missing"),
                          ([str(tmp_path / "on0"), str(rendered["capture"]), "-o", str(jpg)],
                           f"-o {jpg}: the report's picture is written as a .png file"),
                          ([str(tmp_path / "on0"), str(rendered["capture"]), "-o", str(folder)],
                           f"-o {folder}: {folder} is a folder")):
        status = main(["capture", "compare", *args, "--white-level", "1023"] + ([] if "-o" in args else
                                                                              ["-o", str(report)]))
        _, err = capsys.readouterr()
        assert status == 2 and message in err and err.count("\n") == 1, err
    assert not report.exists() and not any(folder.iterdir())


def test_one_frame_against_a_lit_rendering(rendered, tmp_path, capsys):
    """A still scene lit from the ceiling (ambient 4 times the projector's light: blocks between the dots
    for the spatial estimate) rendered with the known noise, its first frame as the recording: `capture
    compare` measures the rendering as it measures that one frame (each of its frames alone, from flat
    regions: the shot noise alike, where over time it reads about 13% lower), and fit-sensor --compare
    takes the spatial estimate's bias out, calibrated on the rendering's scenes. Against the dark
    rendering of the other tests, whose single frames cannot be measured so, it says so."""
    lit = {"extra_lights": [0, 0], "ceiling_light": [100.0, 100.0], "ambient_ratio": [4.0, 4.0]}
    config = still_scenes.still_config(TINY, SCALE, KNOWN, render={"samples": 1}, lighting=lit)
    generate(config, tmp_path / "lit", "train", 1, seed=1, workers=1, progress=False)
    write_frames(dataset.read_scene(dataset.open_dataset(tmp_path / "lit").scenes[0].path).frames[:1],
                 tmp_path / "one")
    report = tmp_path / "report.png"
    status = main(["capture", "compare", str(tmp_path / "one"), str(tmp_path / "lit"), "--white-level",
                   "1023", "-o", str(report)])
    out, err = capsys.readouterr()
    assert status == 0, err
    assert "note: the recording has one frame per scene: the rendering is measured as one-frame" in out
    record = json.loads(report.with_suffix(".json").read_text())
    assert record["noise_measured"] == {"recording": "spatial", "rendering": "spatial"}
    shot = next(row for row in record["rows"] if row["statistic"] == "shot noise at full scale")
    assert shot["ratio"] == pytest.approx(1, abs=0.06)
    status, out, err = fit_sensor(capsys, tmp_path / "one", "--white-level", 1023, "--compare",
                                  tmp_path / "lit", "-o", tmp_path / "sensor.toml")
    assert status == 0, err
    # one small frame measures its noise to about 11% (its error): the correction's accuracy is checked on
    # larger frames (tests/capture/test_fit_sensor_inputs.py); here that it is made and noted
    table = tomllib.loads((tmp_path / "sensor.toml").read_text())["sensor"]
    assert table["shot_noise"] == pytest.approx(KNOWN["shot_noise"], rel=0.15)
    assert table["shot_noise"] < shot["recording"]
    assert "the spatial estimate's bias taken out" in (tmp_path / "sensor.toml").read_text()
    status = main(["capture", "compare", str(tmp_path / "one"), str(rendered["capture"]), "--white-level",
                   "1023", "-o", str(report)])
    out, err = capsys.readouterr()
    assert status == 0, err
    assert "but the rendering's single frames cannot be measured so" in out
    assert json.loads(report.with_suffix(".json").read_text())["noise_measured"]["rendering"] == "temporal"
