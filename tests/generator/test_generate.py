"""`dotsim generate` end to end with real Cycles (tiny scenes), post-render against analytic values,
resume, determinism, and bad input stopping before anything is written."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import OpenEXR
import pytest

from commands.cli import main as dotsim_main
from dotsim import config_schema, dataset
from dotsim.channels import rendered_channels
from dotsim.patterns import load_pattern
from dotsim.rig.files import load_rig_file, rig_file_json
from dotsim.rig.options import with_rig_options
from dotsim.rig.presets import get_preset
from dotsim.sensor.model import SensorStreams
from generator.blender.frame_recipe import RAW_PASSES
from generator.config import ConfigError, config_from_dict, load_config
from generator.driver import generate
from generator.engines.steps import RUN_FILE, prepare_run
from generator.post_render import make_frame
from generator.render_worker import LOG_DIR
from generator.run_request import RunRequest
from generator.sample_scene import SceneResources, sample_scene_spec
from generator.scene_spec import camera_views
from tests.capture_inputs import write_on_off_frames

REPO = Path(__file__).resolve().parents[2]
TINY = REPO / "dotsim" / "configs" / "tiny.toml"


def run_cli(*args: str) -> int:
    return dotsim_main(["generate", "--no-progress", *args])


# ----------------------------------------------------------------------------- post-render, no Blender


def spec_with_rig(rig, config):
    """A sampled spec of `config` whose rig is `rig` (make_frame reads its rig, sensor and masks)."""
    spec = sample_scene_spec(config, 0, 0, "train", SceneResources("/p.png", "0" * 64))
    return replace(spec, rig=rig, cameras=camera_views(rig))


def test_make_frame_against_analytic_wall():
    rig = get_preset("structure_core").scaled(0.05)
    h, w = rig.camera.height, rig.camera.width
    depth = np.full((h, w), 2.0, np.float32)
    depth[10:20, 10:20] = 1.0           # a box in front of the wall
    depth[:3, -5:] = 1e10               # nothing hit (Blender's Z pass value)
    depth[-3:, :4] = 25.0               # beyond max_depth (20 m)
    ambient = np.full((h, w), 0.1, np.float32)
    flood_only = np.ones((h, w), np.float32)
    flood_only[:, 30:33] = 0.0          # a projector shadow
    projector = flood_only * np.random.default_rng(0).uniform(0, 1, (h, w)).astype(np.float32)
    config = config_from_dict({})
    raw = {"projector": projector, "flood": flood_only, "ambient": ambient, "depth": depth,
           "projector_direct": projector, "flood_direct": flood_only}  # no indirect light here
    frame = make_frame(raw, spec_with_rig(rig, config), [SensorStreams(np.random.default_rng(1))])
    # Every stored channel; disparity is derived from depth on read (format 2).
    assert set(frame) == set(dataset.RENDERED_CHANNELS) - {"disparity"}
    disparity = dataset.ground_truth_disparity(frame["depth"], rig)

    assert np.isinf(frame["depth"][:3, -5:]).all()
    np.testing.assert_array_equal(frame["depth"][5:, :-5][np.isfinite(depth[5:, :-5])],
                                  depth[5:, :-5][np.isfinite(depth[5:, :-5])])
    # Disparity d = fx b / z and, for this rectified rig, the projector column
    # xp = fxp (x - b) / z + cxp with x = (u - cx) z / fx.
    u = np.arange(w)[None, :].repeat(h, 0)
    fx, b = rig.camera.fx, rig.baseline
    valid = depth <= 20.0
    np.testing.assert_allclose(disparity[valid], (fx * b / depth)[valid], rtol=1e-6)
    x = (u - rig.camera.cx) * depth / fx
    column = rig.projector.fx * (x - b) / depth + rig.projector.cx
    np.testing.assert_allclose(frame["projector_column"][valid], column[valid], rtol=1e-5, atol=1e-3)
    assert np.isnan(disparity[~valid]).all() and np.isnan(frame["projector_column"][~valid]).all()

    np.testing.assert_array_equal(frame["flood"], ambient + flood_only)
    np.testing.assert_array_equal(frame["ambient"], ambient)
    assert not frame["visibility"][:, 30:33].any() and frame["visibility"][:, :29].all()
    assert frame["edge"][15, 9] and frame["edge"][15, 20] and not frame["edge"][30, 45]
    levels = frame["ir"].astype(np.float64) * 1023
    np.testing.assert_allclose(levels, np.round(levels), atol=1e-3)  # 10-bit sensor


def test_make_frame_names_bad_raw_passes():
    rig = get_preset("structure_core").scaled(0.05)
    raw = {name: np.zeros((3, 3), np.float32) for name in RAW_PASSES}
    with pytest.raises(ValueError, match="scene 4 frame 1: raw pass 'projector' has shape"):
        make_frame(raw, spec_with_rig(rig, config_from_dict({})), [SensorStreams(np.random.default_rng(0))],
                   where="scene 4 frame 1")
    del raw["depth"]
    with pytest.raises(ValueError, match=r"lack \['depth'\]"):
        make_frame(raw, spec_with_rig(rig, config_from_dict({})), [SensorStreams(np.random.default_rng(0))])


# ----------------------------------------------------------------------------- bad input: nothing written


@pytest.mark.parametrize("text, expected", [
    ("[scene]\nobject_cont = [1, 2]\n", 'did you mean "object_count"'),
    ("[render]\nsamples = 0\n", "[render] samples = 0: out of range"),
    ('[pattern]\nsource = "file"\npath = "missing.png"\n', "missing.png"),
    ('[assets]\nsource = "cache"\ncache_dir = "no_cache"\n', "no_cache"),
])
def test_config_errors_stop_before_writing(tmp_path, capsys, text, expected):
    config = tmp_path / "bad.toml"
    config.write_text(text)
    out = tmp_path / "out"
    assert run_cli("--config", str(config), "--out", str(out), "--split", "train", "--scenes", "1") == 2
    error = capsys.readouterr().err
    assert str(config) in error and expected in error
    assert not out.exists()


def test_unreadable_pattern_file_stops_before_writing(tmp_path, capsys):
    (tmp_path / "bad.png").write_text("not an image")
    config = tmp_path / "c.toml"
    config.write_text('[pattern]\nsource = "file"\npath = "bad.png"\n')
    out = tmp_path / "out"
    assert run_cli("--config", str(config), "--out", str(out), "--split", "train", "--scenes", "1") == 2
    error = capsys.readouterr().err
    assert str(config) in error and str(tmp_path / "bad.png") in error
    assert not out.exists()


@pytest.mark.parametrize("option", ["--scenes", "--start", "--workers", "--seed"])
def test_integer_options_name_the_value_and_the_range(tmp_path, capsys, option):
    args = ["--config", str(TINY), "--out", str(tmp_path / "out"), "--split", "train", "--scenes", "1"]
    with pytest.raises(SystemExit) as exit_code:
        run_cli(*args, option, "abc")
    low = 1 if option in ("--scenes", "--workers") else 0
    assert exit_code.value.code == 2
    assert f"argument {option}: 'abc': allowed: an integer >= {low}" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def one_dot_png(folder: Path, value: int) -> str:
    """A 51 x 51 8-bit PNG, black but for one pixel of `value`; returns its name."""
    import cv2

    image = np.zeros((51, 51), np.uint8)
    image[10, 10] = value
    assert cv2.imwrite(str(folder / f"dot_{value}.png"), image)
    return f"dot_{value}.png"


@pytest.mark.parametrize("make, expected", [
    (lambda folder: (folder / "pattern.png").mkdir() or "pattern.png", "is a folder, not a file"),
    (lambda folder: one_dot_png(folder, 1), "brightest pixel is 0.0039 of full scale (below 1/16)"),
    (lambda folder: one_dot_png(folder, 255), "only 1 of 2601 pixels are above half the brightest value"),
])
def test_pattern_file_without_signal_stops_before_writing(tmp_path, capsys, make, expected):
    name = make(tmp_path)
    config = tmp_path / "c.toml"
    config.write_text(f'[pattern]\nsource = "file"\npath = "{name}"\n')
    out = tmp_path / "out"
    assert run_cli("--config", str(config), "--out", str(out), "--split", "train", "--scenes", "1") == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and name in error and expected in error, error
    assert not out.exists()


def test_unwritable_output_stops_before_writing(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert run_cli("--config", str(TINY), "--out", str(blocker / "out"), "--split", "train",
                   "--scenes", "1") == 2
    assert "not a directory" in capsys.readouterr().err
    assert run_cli("--config", str(TINY), "--out", "/proc/dotsim", "--split", "train", "--scenes", "1") == 2
    assert "not writable" in capsys.readouterr().err


def test_bad_blender_executable(tmp_path):
    with pytest.raises(ConfigError, match="--blender /no/blender: not an executable"):
        generate(load_config(TINY), tmp_path / "out", "train", 1, blender="/no/blender", progress=False)
    assert not (tmp_path / "out").exists()


# ----------------------------------------------------------------------------- real Cycles


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """Two tiny scenes rendered by one worker (shared by the tests below)."""
    out = tmp_path_factory.mktemp("gen") / "a"
    summary = generate(load_config(TINY), out, "train", 2, seed=3, progress=False)
    return out, summary


def test_generate_writes_a_readable_dataset(rendered):
    out, summary = rendered
    assert (summary.done, summary.skipped, summary.failed, summary.frames) == (2, 0, [], 8)
    data = dataset.open_dataset(out)
    assert [s.scene_index for s in data.scenes] == [0, 1]
    config = load_config(TINY)
    for ref in data.scenes:
        scene = dataset.read_scene(ref.path)
        assert scene.meta["config"] == config.to_dict()  # the full resolved config is recorded
        assert scene.meta["split"] == "train" and scene.meta["base_seed"] == 3
        assert len(scene.frames) == 4
        for frame in scene.frames:
            assert frame["ir"].shape == (90, 122)
            finite = np.isfinite(frame["depth"])
            assert finite.mean() > 0.95  # a closed room: nearly every ray hits something
            # The stored ground truth follows from the stored depth (d = fx b / z).
            rig = get_preset("structure_core").scaled(0.1)
            near = finite & (frame["depth"] <= rig.max_depth)
            np.testing.assert_allclose(frame["disparity"][near],
                                       rig.camera.fx * rig.baseline / frame["depth"][near], rtol=1e-5)
            assert 0.05 < frame["visibility"].mean() <= 1.0
            assert frame["ir"].max() > 0.5  # auto exposure reached the target level
        texture_paths = {o["material"]["texture"]["path"] for o in scene.meta["objects"]
                         if o["material"]["texture"]}
        assert texture_paths and all((out / p).is_file() for p in texture_paths)
    pattern = load_pattern(dataset.pattern_path(out))
    assert pattern.image.shape == (307, 307)  # the scaled projector's resolution
    assert pattern.sha256 == scene.meta["pattern"]["sha256"]


def test_exr_compression_zip_stores_the_same_frames_in_zip_files(rendered, tmp_path):
    """[output] exr_compression = "zip": scene 0 again, its frame files ZIP-compressed (the OpenEXR
    package reads their header), their values those of the default ZSTD render, bit for bit."""
    import OpenEXR

    source, _ = rendered
    config = load_config(TINY)
    config = replace(config, output=replace(config.output, exr_compression="zip"))
    assert generate(config, tmp_path / "zip", "train", 1, seed=3, progress=False).done == 1
    zipped = dataset.read_scene(dataset.scene_dir(tmp_path / "zip", 0, 2))
    original = dataset.read_scene(dataset.scene_dir(source, 0, 2))
    assert zipped.meta["config"]["output"]["exr_compression"] == "zip"
    for k, (a, b) in enumerate(zip(zipped.frames, original.frames, strict=True)):
        for path, compression in ((zipped.path, "ZIP_COMPRESSION"), (original.path, "ZSTD_COMPRESSION")):
            header = OpenEXR.File(str(path / dataset.frame_name(k))).header()
            assert header["compression"] == getattr(OpenEXR, compression)
        assert a.keys() == b.keys()
        for name in a:
            np.testing.assert_array_equal(a[name], b[name])


def test_resume_skips_complete_and_redoes_partial(rendered, tmp_path):
    source, _ = rendered
    out = tmp_path / "resume"
    shutil.copytree(source, out)
    shard = out / "shard_00000"
    first_scene = (shard / "scene_0000000" / "scene.json").read_bytes()
    # Scene 1 half-written by a crashed worker (a temp dir whose pid is not alive), final dir gone.
    shutil.move(shard / "scene_0000001", shard / ".tmp-scene_0000001-999999999")
    (shard / ".tmp-scene_0000001-999999999" / "frame_3.exr").unlink()
    summary = generate(load_config(TINY), out, "train", 3, seed=3, progress=False)
    assert (summary.done, summary.skipped, summary.failed) == (2, 1, [])
    assert not list(shard.glob(".tmp-*"))
    assert (shard / "scene_0000000" / "scene.json").read_bytes() == first_scene  # untouched
    assert [s.scene_index for s in dataset.open_dataset(out).scenes] == [0, 1, 2]
    # The redone scene equals the original rendering of scene 1.
    redone = dataset.read_scene(shard / "scene_0000001")
    original = dataset.read_scene(source / "shard_00000" / "scene_0000001")
    for a, b in zip(redone.frames, original.frames, strict=True):
        for name in a:
            np.testing.assert_array_equal(a[name], b[name])
    # Once complete, a rerun renders nothing.
    again = generate(load_config(TINY), out, "train", 3, seed=3, progress=False)
    assert (again.done, again.skipped) == (0, 3)


def test_same_seed_same_dataset_regardless_of_workers(rendered, tmp_path):
    source, _ = rendered
    out = tmp_path / "twice"
    summary = generate(load_config(TINY), out, "train", 2, workers=2, seed=3, progress=False)
    assert summary.done == 2
    for index in (0, 1):
        a = dataset.read_scene(dataset.scene_dir(source, index, 2))
        b = dataset.read_scene(dataset.scene_dir(out, index, 2))
        assert a.meta == b.meta
        for fa, fb in zip(a.frames, b.frames, strict=True):
            for name in fa:
                np.testing.assert_array_equal(fa[name], fb[name])


def test_render_scenes_in_a_fresh_process_as_another_front_end_would(rendered, tmp_path):
    """prepare_run once, render_scenes(job, indices) in a process of its own (as a Ray or Slurm task
    would), then seal: the scenes equal those generate() wrote, files and metadata alike."""
    import pickle
    import subprocess
    import sys

    source, _ = rendered
    out = tmp_path / "front_end"
    job = prepare_run(RunRequest(load_config(TINY), out, "train", 2, seed=3))
    (tmp_path / "job.pickle").write_bytes(pickle.dumps(job))
    task = ("import pickle, sys; from generator.render_worker import render_scenes; "
            "job = pickle.load(open(sys.argv[1], 'rb')); "
            "print([(r.index, r.ok, r.frames) for r in render_scenes(job, [1, 0])])")
    proc = subprocess.run([sys.executable, "-c", task, str(tmp_path / "job.pickle")], cwd=REPO,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "[(1, True, 4), (0, True, 4)]" in proc.stdout
    dataset.seal_dataset(out)
    for index in (0, 1):
        a = dataset.scene_dir(source, index, 2)
        b = dataset.scene_dir(out, index, 2)
        assert sorted(p.name for p in a.iterdir()) == sorted(p.name for p in b.iterdir())
        for path in a.iterdir():
            assert path.read_bytes() == (b / path.name).read_bytes(), path.name


def test_other_seed_or_config_refused_on_an_existing_dataset(rendered, tmp_path):
    source, _ = rendered
    out = tmp_path / "mixed"
    shutil.copytree(source, out)
    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    with pytest.raises(ConfigError, match="base_seed"):
        generate(load_config(TINY), out, "train", 1, seed=4, progress=False)
    changed = tmp_path / "changed.toml"
    changed.write_text(TINY.read_text().replace("samples = 1", "samples = 2"))
    with pytest.raises(ConfigError, match=r"\[render\]"):
        generate(load_config(changed), out, "train", 1, seed=3, progress=False)
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == before
    assert json.loads((out / RUN_FILE).read_text())["base_seed"] == 3
    assert not (out / LOG_DIR).exists()


CACHE_MANIFEST = """
[split]
name = "test"
clutter_density = 2.0

[[meshes]]
name = "blob"
generator = "noise_displaced_sphere"
seeds = [0, 1]
params = { subdivisions = 2 }
scale = [0.1, 0.3]
license = "CC0-1.0"

[[textures]]
name = "noise"
generator = "fractal_noise"
seeds = [0, 1]
params = { size = 64, octaves = 3 }
scale = [0.2, 0.5]
license = "CC0-1.0"
"""


def test_generate_from_asset_cache(tmp_path):
    from assets_manifest.cache import build_asset_cache, load_asset_cache
    from assets_manifest.manifest import load_manifest

    manifest = tmp_path / "test.toml"
    manifest.write_text(CACHE_MANIFEST)
    build_asset_cache(load_manifest(manifest), tmp_path / "cache", "test", progress=False,
                      log=lambda *args: None)
    config_path = tmp_path / "cached.toml"
    config_path.write_text(TINY.read_text() + '\n[assets]\nsource = "cache"\ncache_dir = "cache"\n'
                           '\n[motion]\ntranslation = 0.0\nrotation = 0.0\n')
    config = load_config(config_path)
    out = tmp_path / "out"
    summary = generate(config, out, "test", 1, progress=False)
    assert summary.done == 1
    scene = dataset.read_scene(dataset.scene_dir(out, 0, 2))
    cache = load_asset_cache(tmp_path / "cache", "test")
    objects = [o for o in scene.meta["objects"] if o["name"].startswith("object_")]
    # The cache's clutter density (2) multiplies the config's object count range [8, 16].
    assert 16 <= len(objects) <= 32
    assert {o["mesh"]["path"] for o in objects} <= {m.path for m in cache.meshes}
    assert all(o["mesh"]["kind"] == "asset" for o in objects)
    # Scaled so the largest extent lies in the asset's scale hint (or half its distance, if less).
    pose = np.array(scene.meta["poses"][0])
    for o in objects:
        with np.load(o["mesh"]["path"]) as arrays:
            extent = np.ptp(arrays["vertices"], axis=0).max() * o["scale"][0]
        distance = np.linalg.norm(np.array(o["location"]) - pose[:3, 3])
        assert min(0.1, distance / 2) * 0.999 <= extent <= min(0.3, distance / 2) * 1.001
    textures = {o["material"]["texture"]["path"] for o in scene.meta["objects"] if o["material"]["texture"]}
    assert textures and textures <= {t.path for t in cache.textures}
    assert not (out / "textures").exists()  # no built-in textures in cache mode


# ----------------------------------------------------------------------------- --blender EXE path


def test_blender_executable_path(rendered, tmp_path):
    """The bpy-less path: spec JSON -> `EXE --background --python run_in_blender.py -- ...` -> raw npz.

    No Blender executable is installed here, so EXE is a two-line shell script that runs the same
    entry script with the bpy module (run_in_blender.py accepts both invocations); everything after
    it - spec files, batches, npz reading, post-render - is the real path and must reproduce the
    in-process rendering exactly."""
    import sys

    shim = tmp_path / "blender"
    shim.write_text('#!/bin/sh\n[ "$1" = --version ] && { echo "Blender 5.0.1 (bpy module)"; exit 0; }\n'
                    f'while [ "$1" != --python ]; do shift; done; shift\nexec {sys.executable} "$@"\n')
    shim.chmod(0o755)
    source, _ = rendered
    out = tmp_path / "exe"
    assert run_cli("--config", str(TINY), "--out", str(out), "--split", "train", "--scenes", "2",
                   "--seed", "3", "--blender", str(shim)) == 0
    for index in (0, 1):
        a = dataset.read_scene(dataset.scene_dir(source, index, 2))
        b = dataset.read_scene(dataset.scene_dir(out, index, 2))
        assert b.meta["versions"]["blender"] == "Blender 5.0.1 (bpy module)"
        assert {k: v for k, v in a.meta.items() if k != "versions"} == \
            {k: v for k, v in b.meta.items() if k != "versions"}
        for fa, fb in zip(a.frames, b.frames, strict=True):
            for name in fa:
                np.testing.assert_array_equal(fa[name], fb[name])


def test_failing_scenes_are_logged_and_the_run_goes_on(tmp_path, capsys):
    # /bin/false is an executable that renders nothing: every scene fails, each with a log.
    out = tmp_path / "fail"
    assert run_cli("--config", str(TINY), "--out", str(out), "--split", "train", "--scenes", "3",
                   "--blender", "/bin/false") == 1
    captured = capsys.readouterr()
    assert "0 scenes rendered (0 frames), 0 already complete, 3 failed" in captured.err
    logs = sorted(p.name for p in (out / LOG_DIR).iterdir())
    assert logs == [f"scene_000000{k}.log" for k in range(3)]
    assert "blender wrote no scene_0000001_raw.npz" in (out / LOG_DIR / logs[1]).read_text()
    assert not list(out.glob("shard_*/scene_*"))


def test_generate_with_rig_file_renders_its_pinhole_model(tmp_path, capsys):
    """`--rig FILE`: a stereo calibration with lens distortion (written by cv2.FileStorage) renders the
    file's pinhole rig at the config's scale and says in one line that real frames are rectified to it."""
    path = tmp_path / "sensor.yaml"
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in (("K1", np.array([[600.0, 0, 320.5], [0, 600.0, 240.5], [0, 0, 1]])),
                       ("D1", np.array([[0.1, -0.2, 0.0, 0.0, 0.0]])),
                       ("K2", np.array([[1200.0, 0, 800.0], [0, 1200.0, 600.0], [0, 0, 1]])),
                       ("R", np.eye(3)), ("T", np.array([[-0.06], [0.0], [0.0]]))):
        storage.write(key, value)
    for key, value in (("image_width", 640), ("image_height", 480), ("projector_width", 1600),
                       ("projector_height", 1200)):
        storage.write(key, value)
    storage.release()
    assert run_cli("--config", "tiny", "--rig", str(path), "--out", str(tmp_path / "d"), "--split", "train",
                   "--scenes", "1") == 0
    note = [line for line in capsys.readouterr().err.splitlines() if "rectified" in line]
    assert len(note) == 1 and "lens distortion" in note[0] and "64 x 48 px" in note[0]
    scene = dataset.read_scene(dataset.open_dataset(tmp_path / "d").scenes[0].path)
    expected = load_rig_file(path).rig.scaled(0.1)
    rig = scene.meta["rig"]
    assert rig["camera"] == expected.camera.to_dict() and rig["projector"] == expected.projector.to_dict()
    assert rig["projector_translation"] == [0.06, 0.0, 0.0]
    frame = scene.frames[0]
    assert frame["ir"].shape == (48, 64)
    near = np.isfinite(frame["depth"]) & (frame["depth"] <= rig["max_depth"])
    np.testing.assert_allclose(frame["disparity"][near], 60.0 * 0.06 / frame["depth"][near], rtol=1e-5)


def test_generate_with_a_ros_camera_info_by_flag_prints_the_rig_it_renders(tmp_path, capsys):
    """`--camera-file` with a ROS camera_info: the file's pinhole camera with the config's preset projector
    renders, the rig is named after both, and generate says so when it starts: the rig in one line
    (as `dotsim rig show` prints it), the camera-only note and the lens note."""
    from tests.capture.test_capture_rectify import LENS_K, ros_camera_info

    ros = ros_camera_info(tmp_path / "ir.yaml")
    assert run_cli("--config", "tiny", "--camera-file", str(ros), "--out", str(tmp_path / "d"), "--split",
                   "train", "--scenes", "1") == 0
    out, err = capsys.readouterr()
    name = "ir_camera (camera) + structure_core (projector)"
    assert out.splitlines()[0].startswith(f"rig {name}: camera 32 x 24 px, f 26.00 px, field of view ")
    assert f"{ros} calibrates the camera alone: the projector and its pose are those of preset " \
        "structure_core" in err
    assert "the calibrated camera has lens distortion" in err
    rig = dataset.read_scene_meta(dataset.open_dataset(tmp_path / "d").scenes[0].path)["rig"]
    focal = (LENS_K[0, 0] + LENS_K[1, 1]) / 2 * 0.1
    assert rig["name"] == name and (rig["camera"]["width"], rig["camera"]["fx"]) == (32, focal)
    assert rig["projector"] == get_preset("structure_core").scaled(0.1).projector.to_dict()
    # the same file as --rig: a camera alone, so the same rig
    tiny = load_config("tiny")
    assert with_rig_options(tiny.rig, tiny.source, str(ros))[1].rig.to_dict() == rig


def test_generate_rig_option_errors(tmp_path, capsys):
    tiny = load_config("tiny")
    assert with_rig_options(tiny.rig, tiny.source, "kinect_v1")[0].preset == "kinect_v1"
    for spec, message in (("nosuch", "--rig 'nosuch': neither a preset"),
                          (str(tmp_path / "none.yaml"), "none.yaml: rig file not found")):
        assert run_cli("--config", "tiny", "--rig", spec, "--out", str(tmp_path / "d"), "--split", "train",
                       "--scenes", "1") == 2
        assert message in capsys.readouterr().err
    assert not (tmp_path / "d").exists()


# ----------------------------------------------------------------------------- the stereo pair


def tiny_d415(stereo: bool):
    """The tiny config with a RealSense D415 at 0.1 scale (128 x 72 px), its pair rendered or not."""
    data = config_schema.read_toml(TINY)
    data["rig"] = {"preset": "realsense_d415", "scale": 0.1, "stereo": stereo, "max_depth": 10.0}
    return config_from_dict(data, source=str(TINY), base_dir=REPO)


def test_stereo_pair_is_written_beside_the_left_camera_which_it_leaves_as_it_was(tmp_path):
    """[rig] stereo = true: format 2.1 scenes with the right IR, the stereo mask and the stereo
    disparity fx B / z (derived on read); every channel of the left camera is what the same config
    without the pair writes, byte for byte (the scene's mono frames record format 2.0)."""
    mono, pair = tmp_path / "mono", tmp_path / "pair"
    assert generate(tiny_d415(False), mono, "train", 1, seed=4, progress=False).done == 1
    assert generate(tiny_d415(True), pair, "train", 1, seed=4, progress=False).done == 1
    rig = get_preset("realsense_d415").scaled(0.1)
    scene = dataset.read_scene(dataset.open_dataset(pair).scenes[0].path)
    alone = dataset.read_scene(dataset.open_dataset(mono).scenes[0].path)
    assert scene.meta["format_version"] == "2.1" and alone.meta["format_version"] == "2.0"
    assert set(scene.meta["channels"]) == set(rendered_channels(stereo=True))
    assert scene.meta["config"]["rig"]["stereo"] is True
    for frame, mono_frame in zip(scene.frames, alone.frames, strict=True):
        for name, value in mono_frame.items():
            np.testing.assert_array_equal(frame[name], value, err_msg=name)
        near = np.isfinite(frame["depth"]) & (frame["depth"] <= 10.0)
        np.testing.assert_allclose(frame["stereo_disparity"][near],
                                   rig.camera.fx * 0.055 / frame["depth"][near], rtol=1e-6)
        assert 0.3 < frame["stereo_visibility"].mean() < 1.0
        assert frame["ir_right"].max() > 0.5 and not np.array_equal(frame["ir_right"], frame["ir"])
    frame_file = OpenEXR.File(str(scene.path / "frame_0.exr"), separate_channels=True)
    assert "stereo_disparity" not in frame_file.channels()
    assert frame_file.header()["dotsim_format_version"] == "2.1"


@pytest.mark.parametrize("config, rig, message", [
    ('[rig]\npreset = "kinect_v1"\nstereo = true\n', None, "rig 'kinect_v1' has no second IR camera"),
    ('[rig]\npreset = "realsense_d435"\nstereo = true\n', "kinect_v1", "rig 'kinect_v1' has no second"),
    ('[rig]\nstereo = true\n', "tilted.json", "has its second IR camera at [0.05, 0.0, 0.01], not on the "
                                                "camera's x axis to its right"),
])
def test_a_pair_asked_of_a_rig_without_one_stops_before_writing(tmp_path, capsys, config, rig, message):
    path = tmp_path / "c.toml"
    path.write_text(config)
    tilted = replace(get_preset("realsense_d435"), second_camera_translation=(0.05, 0.0, 0.01))
    (tmp_path / "tilted.json").write_bytes(rig_file_json(tilted))
    out = tmp_path / "out"
    options = ["--rig", str(tmp_path / rig) if rig == "tilted.json" else rig] if rig else []
    assert run_cli("--config", str(path), *options, "--out", str(out), "--split", "train",
                   "--scenes", "1") == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "[rig] stereo = true" in error and message in error, error
    assert "allowed: a rig whose second_camera_translation is [B, 0, 0] with B > 0" in error
    assert not out.exists()


def test_generate_refuses_a_dataset_of_real_captures(tmp_path, capsys):
    """A dataset holds one kind of data (issue 37, item 4): `generate` into a folder `capture import`
    made is one line, and the folder stays as it was."""
    rig = get_preset("structure_core").scaled(0.1)
    write_on_off_frames(tmp_path, (rig.camera.height, rig.camera.width), seed=0)
    out = tmp_path / "real"
    assert dotsim_main(["capture", "import", "--on", str(tmp_path / "on"), "--off", str(tmp_path / "off"),
                        "--scale", "0.1", "--frames-per-scene", "2", "--scenes-per-shard", "2",
                        "--out", str(out)]) == 0
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    capsys.readouterr()
    assert run_cli("--config", str(TINY), "--out", str(out), "--split", "test", "--scenes", "2") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{out}: holds a dotsim dataset of captured scenes" in err, err
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before


def test_test_scenes_of_the_training_meshes_are_new_scenes(tmp_path):
    """[assets] test_assets = "train" (`dotsim generate --test-assets train`): the test split's scenes
    draw the training cache's meshes and clutter density (DepthInSpace's like-for-like test), and with
    another seed they are other scenes than the training ones; the default keeps the splits disjoint."""
    from assets_manifest.cache import build_asset_cache, load_asset_cache
    from assets_manifest.manifest import load_manifest
    from generator.resources import split_assets

    for split, seeds in (("train", "[0, 1]"), ("test", "[5, 6]")):
        manifest = tmp_path / f"{split}.toml"
        manifest.write_text(CACHE_MANIFEST.replace('name = "test"', f'name = "{split}"')
                            .replace("seeds = [0, 1]", f"seeds = {seeds}", 1))
        build_asset_cache(load_manifest(manifest), tmp_path / "cache", split, progress=False,
                          log=lambda *args: None)
    mesh_paths = {split: {m.path for m in load_asset_cache(tmp_path / "cache", split).meshes}
                  for split in ("train", "test")}
    assert mesh_paths["train"] and not mesh_paths["train"] & mesh_paths["test"]
    config_path = tmp_path / "cached.toml"
    config_path.write_text(TINY.read_text() + '\n[assets]\nsource = "cache"\ncache_dir = "cache"\n')
    disjoint = load_config(config_path)
    seen = replace(disjoint, assets=replace(disjoint.assets, test_assets="train"))

    def meshes(config, split, seed, index):
        resources = split_assets(config, split, tmp_path).with_pattern("/data/pattern.png", "ab" * 32)
        spec = sample_scene_spec(config, index, seed, split, resources)
        assert spec.split == split
        return spec, {o.mesh.path for o in spec.objects if o.name.startswith("object_")}

    for index in range(3):
        trained, train_meshes = meshes(disjoint, "train", 0, index)
        tested, test_meshes = meshes(seen, "test", 1, index)
        _, disjoint_meshes = meshes(disjoint, "test", 1, index)
        assert train_meshes <= mesh_paths["train"] and test_meshes <= mesh_paths["train"]
        assert disjoint_meshes <= mesh_paths["test"]
        placed = lambda spec: [o.location for o in spec.objects if o.name.startswith("object_")]  # noqa: E731
        assert placed(tested) != placed(trained)  # another scene of the same meshes
    # the training cache's clutter density (2, as the manifest says) for both splits' scenes
    assert split_assets(seen, "test", tmp_path).density == split_assets(seen, "train", tmp_path).density
