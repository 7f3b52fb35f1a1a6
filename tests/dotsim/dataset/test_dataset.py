"""The dataset contract: real EXR files written and read back, atomicity, refusals with reasons."""

import hashlib
import json
import os

import numpy as np
import OpenEXR
import pytest

from dotsim import __version__
from dotsim import dataset as ds
from dotsim.rig.presets import get_preset

RIG = get_preset("structure_core").scaled(0.025)  # 30 x 22 camera
H, W = RIG.camera.height, RIG.camera.width


def make_frame(rng):
    depth = rng.uniform(0.3, 20.0, (H, W)).astype(np.float32)
    depth[0, :5] = np.inf  # no hit
    column = rng.uniform(0, RIG.projector.width, (H, W)).astype(np.float32)
    column[0, :5] = np.nan
    return {
        "ir": np.rint(rng.uniform(0, 1, (H, W)) * 1023) / 1023,  # 10-bit sensor values
        "ambient": rng.uniform(0, 2, (H, W)).astype(np.float32),
        "flood": rng.uniform(0, 50, (H, W)),
        "depth": depth,
        "visibility": rng.uniform(size=(H, W)) > 0.3,
        "edge": (rng.uniform(size=(H, W)) > 0.8).astype(np.uint8),
        "projector_column": column,
        # fx * b / z, the one disparity the writer accepts (format 2 derives it on read)
        "disparity": np.where(np.isfinite(depth), RIG.camera.fx * RIG.baseline / depth.astype(np.float64),
                              np.nan).astype(np.float32),
    }


def make_meta(index, split="train"):
    poses = [[[1.0, 0, 0, 0.01 * k], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]] for k in range(4)]
    return {
        "split": split, "seed": 1000 + index, "config": {"scenes": 7, "name": "unit"},
        "rig": RIG.to_dict(), "pattern": {"source": "procedural", "sha256": "ab" * 32, "width": 77,
                                          "height": 77, "params": {"n_dots": 500}},
        "poses": poses, "objects": [{"name": "wall", "albedo": 0.5}], "lights": [],
        "render": {"samples": 1}, "versions": {"bpy": "5.0.1"},
    }


def write(root, index, seed=0, spp=2, split="train"):
    rng = np.random.default_rng(seed + index)
    frames = [make_frame(rng) for _ in range(4)]
    path = ds.write_scene(root, index, make_meta(index, split), frames, scenes_per_shard=spp)
    return path, frames


def test_round_trip_every_channel_and_field(tmp_path):
    path, frames = write(tmp_path, 3)
    assert path == tmp_path / "shard_00001" / "scene_0000003"  # 3 // 2 scenes per shard
    assert sorted(p.name for p in path.iterdir()) == ["frame_0.exr", "frame_1.exr", "frame_2.exr",
                                                      "frame_3.exr", "scene.json"]
    ds.seal_dataset(tmp_path)
    scene = ds.read_scene(path)
    expected_meta = make_meta(3)
    for key, value in expected_meta.items():
        assert scene.meta[key] == value, key
    assert scene.meta["format_version"] == "2.0"  # no channel of 2.1: recorded as 2.0
    assert scene.meta["dotsim_version"] == __version__
    assert scene.meta["scene_index"] == 3 and scene.meta["frame_count"] == 4
    for got, sent in zip(scene.frames, frames, strict=True):
        assert set(got) == set(ds.RENDERED_CHANNELS)
        for name in ds.RENDERED_CHANNELS:
            dtype = ds.FRAME_CHANNELS[name]
            assert got[name].dtype == dtype, name
            # Bit-exact for the stored dtype (NaN == NaN here); masks as 0/1 uint8.
            want = np.asarray(sent[name]).astype(dtype)
            assert np.array_equal(got[name].view(np.uint8), want.view(np.uint8)), name
        assert np.isinf(got["depth"][0, :5]).all() and np.isnan(got["projector_column"][0, :5]).all()
        # 10-bit IR survives half precision: the sensor code is recovered exactly.
        codes = np.rint(np.asarray(sent["ir"]) * 1023)
        assert np.array_equal(np.rint(got["ir"].astype(np.float64) * 1023), codes)
    # The EXR really carries the documented pixel types and compression (checked with OpenEXR
    # directly); format 2 stores no disparity.
    exr = OpenEXR.File(str(path / "frame_0.exr"), separate_channels=True)
    stored = exr.channels()
    types = {name: stored[name].pixels.dtype for name in stored}
    assert types == {"ir": np.float16, "ambient": np.float16, "flood": np.float16,
                     "depth": np.float32, "projector_column": np.float32,
                     "visibility": np.uint32, "edge": np.uint32}
    assert exr.header()["compression"] == OpenEXR.ZSTD_COMPRESSION


def test_half_precision_limit_is_11_bits():
    # Why FORMAT.md says IR may be stored as half only up to 11-bit sensors.
    for bits, exact in ((10, True), (11, True), (12, False)):
        top = 2**bits - 1
        codes = np.arange(top + 1)
        back = np.rint((codes / top).astype(np.float16).astype(np.float64) * top)
        assert np.array_equal(back, codes) == exact, bits


def test_index_and_shard_checksums_match_files(tmp_path):
    for i in range(5):
        write(tmp_path, i, split="test" if i == 4 else "train")
    (tmp_path / "pattern.png").write_bytes(b"not really a png")
    index = ds.seal_dataset(tmp_path).index
    assert [s["name"] for s in index["shards"]] == ["shard_00000", "shard_00001", "shard_00002"]
    assert [s["scene_count"] for s in index["shards"]] == [2, 2, 1]
    assert index["scene_count"] == 5 and index["frame_count"] == 20
    assert index["split_counts"] == {"train": 4, "test": 1}
    assert index["files"]["pattern.png"] == hashlib.sha256(b"not really a png").hexdigest()
    on_disk = json.loads((tmp_path / "index.json").read_text())
    assert on_disk == index
    for entry in index["shards"]:
        shard_file = tmp_path / entry["name"] / "shard.json"
        assert hashlib.sha256(shard_file.read_bytes()).hexdigest() == entry["sha256"]
        for scene in json.loads(shard_file.read_text())["scenes"]:
            for name, sha in scene["files"].items():
                data = (tmp_path / entry["name"] / scene["name"] / name).read_bytes()
                assert hashlib.sha256(data).hexdigest() == sha
    opened = ds.open_dataset(tmp_path)
    assert [s.scene_index for s in opened.scenes] == [0, 1, 2, 3, 4]
    (tmp_path / "pattern.png").write_bytes(b"another pattern")
    with pytest.raises(ds.FormatError, match=r"pattern\.png: sha256 differs from the one in .*index\.json"):
        ds.open_dataset(tmp_path)
    (tmp_path / "pattern.png").write_bytes(b"not really a png")
    assert [s.scene_index for s in opened.split("test")] == [4]
    frame = ds.read_frame(opened.scenes[2].frame_paths[1])
    assert frame["depth"].shape == (H, W)
    assert "5 scenes, 20 frames in 3 shard(s)" in ds.dataset_summary(tmp_path)


def test_leftover_temp_dir_is_ignored_and_removed(tmp_path):
    write(tmp_path, 0)
    leftover = tmp_path / "shard_00000" / ".tmp-scene_0000001-999999999"  # no such pid
    leftover.mkdir()
    (leftover / "frame_0.exr").write_bytes(b"half written")
    live = tmp_path / "shard_00000" / f".tmp-scene_0000002-{os.getppid()}"  # a running process
    live.mkdir()
    assert not ds.is_scene_complete(tmp_path, 1, scenes_per_shard=2)
    index = ds.seal_dataset(tmp_path).index
    assert index["scene_count"] == 1
    assert [s.scene_index for s in ds.open_dataset(tmp_path).scenes] == [0]
    removed = ds.remove_partial_scenes(tmp_path)
    assert removed == [leftover] and not leftover.exists() and live.exists()
    assert ds.remove_partial_scenes(tmp_path, include_live=True) == [live]


def test_incomplete_scene_is_detected(tmp_path):
    assert not ds.is_scene_complete(tmp_path, 0, scenes_per_shard=2)
    path, _ = write(tmp_path, 0)
    assert ds.is_scene_complete(tmp_path, 0, scenes_per_shard=2)
    (path / "frame_3.exr").unlink()
    assert not ds.is_scene_complete(tmp_path, 0, scenes_per_shard=2)
    with pytest.raises(ds.FormatError, match=r"frame_3\.exr: missing"):
        ds.seal_dataset(tmp_path)


def test_failed_write_leaves_nothing_and_rerun_succeeds(tmp_path):
    rng = np.random.default_rng(0)
    frames = [make_frame(rng) for _ in range(4)]
    frames[2]["visibility"] = np.full((H, W), 2, np.uint8)
    with pytest.raises(ds.FormatError, match=r"scene 5 frame 2: mask channel 'visibility'"):
        ds.write_scene(tmp_path, 5, make_meta(5), frames, scenes_per_shard=2)
    assert list(tmp_path.iterdir()) == []  # frames are encoded (and checked) before anything is written
    frames[2]["visibility"] = frames[2]["visibility"] == 1
    ds.write_scene(tmp_path, 5, make_meta(5), frames, scenes_per_shard=2)
    assert ds.is_scene_complete(tmp_path, 5, scenes_per_shard=2)
    with pytest.raises(ds.FormatError, match="already exists"):
        ds.write_scene(tmp_path, 5, make_meta(5), frames, scenes_per_shard=2)
    with pytest.raises(ds.FormatError, match="scenes_per_shard=2"):
        ds.write_scene(tmp_path, 6, make_meta(6), frames, scenes_per_shard=3)


@pytest.mark.parametrize("change,message", [
    (lambda f, m: f[0].pop("depth"), r"frame 0: missing channel\(s\) \['depth'\]"),
    (lambda f, m: f[1].update(ir=np.zeros((H + 1, W))), r"frame 1: channel 'ir' has shape"),
    (lambda f, m: f[0].update(flood=np.full((H, W), 1e6)), r"'flood' has .* beyond the float16 range"),
    (lambda f, m: f[0]["depth"].__setitem__((1, 1), np.nan), r"depth must be > 0 metres or \+inf"),
    (lambda f, m: f[0].update(normals=np.zeros((H, W))), r"unknown channel\(s\) \['normals'\]"),
    (lambda f, m: m.pop("rig"), r"lacks required key\(s\) \['rig'\]"),
    (lambda f, m: m["poses"].pop(), r"3 poses for 4 frames"),
    (lambda f, m: m.update(seed=float("nan")), r"meta is not JSON-safe"),
])
def test_writer_refuses_bad_input(tmp_path, change, message):
    rng = np.random.default_rng(0)
    frames, meta = [make_frame(rng) for _ in range(4)], make_meta(0)
    change(frames, meta)
    with pytest.raises(ds.FormatError, match=message):
        ds.write_scene(tmp_path, 0, meta, frames, scenes_per_shard=2)
    assert not ds.is_scene_complete(tmp_path, 0, scenes_per_shard=2)


def rewrite_exr(path, channels):
    """Replace a frame file by one written with OpenEXR directly (bypassing the writer's checks)."""
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                 channels).write(str(path))


def test_reader_refuses_missing_channel(tmp_path):
    path, frames = write(tmp_path, 0)
    channels = {k: np.asarray(v).astype(np.uint32 if k in ds.MASK_CHANNELS else ds.FRAME_CHANNELS[k])
                for k, v in frames[1].items() if k != "disparity"}
    rewrite_exr(path / "frame_1.exr", channels)
    with pytest.raises(ds.FormatError, match=r"frame_1\.exr: missing channel\(s\) \['disparity'\]"):
        ds.read_frame(path / "frame_1.exr", verify=False)


def test_reader_refuses_shape_mismatch(tmp_path):
    path, _ = write(tmp_path, 0)
    rewrite_exr(path / "frame_0.exr", {k: np.zeros((H, W + 2), np.uint32 if k in ds.MASK_CHANNELS else d)
                                       for k, d in ds.FRAME_CHANNELS.items()
                                       if k in ds.RENDERED_CHANNELS})
    with pytest.raises(ds.FormatError, match=rf"frame_0\.exr: channel '\w+' has shape \({H}, {W + 2}\), "
                                             rf"expected \({H}, {W}\)"):
        ds.read_scene(path, verify=False)


def test_reader_refuses_flipped_byte(tmp_path):
    path, _ = write(tmp_path, 0)
    ds.seal_dataset(tmp_path)
    frame = path / "frame_2.exr"
    data = bytearray(frame.read_bytes())
    data[len(data) // 2] ^= 0x01
    frame.write_bytes(bytes(data))
    with pytest.raises(ds.FormatError, match=r"frame_2\.exr: sha256 mismatch"):
        ds.read_scene(path)
    # Sealing again does not re-read sealed frames (that is what makes it cheap); verify does.
    assert [p.line() for p in ds.verify_dataset(tmp_path).problems] == [
        f"{frame}: sha256 differs from the one scene.json recorded at write time (file changed or corrupt)"]
    # A frame damaged between writing and its first seal is refused by the seal.
    later, _ = write(tmp_path, 1)
    (later / "frame_0.exr").write_bytes(b"\0" + (later / "frame_0.exr").read_bytes()[1:])
    with pytest.raises(ds.FormatError, match=r"scene_0000001/frame_0\.exr: sha256 .* differs"):
        ds.seal_dataset(tmp_path)
    # shard.json tampering is caught by open_dataset through index.json's checksum.
    shard = tmp_path / "shard_00000" / "shard.json"
    shard.write_text(shard.read_text().replace('"train"', '"test"'))
    with pytest.raises(ds.FormatError, match=r"shard\.json: sha256 differs"):
        ds.open_dataset(tmp_path)


@pytest.mark.parametrize("cut", [0.5, 0.9])
def test_truncated_frame_read_without_verify_names_the_file(tmp_path, cut):
    path, _ = write(tmp_path, 0)
    frame = path / "frame_1.exr"
    data = frame.read_bytes()
    frame.write_bytes(data[:int(len(data) * cut)])  # a copy that stopped early
    with pytest.raises(ds.FormatError, match=r"frame_1\.exr: not a readable OpenEXR file"):
        ds.read_frame(frame, verify=False)
    with pytest.raises(ds.FormatError, match=r"frame_1\.exr: not a readable OpenEXR file"):
        ds.read_scene(path, verify=False)


def test_reader_refuses_unknown_major_version(tmp_path):
    path, _ = write(tmp_path, 0)
    meta_file = path / "scene.json"
    meta = json.loads(meta_file.read_text())
    meta["format_version"] = "3.0"
    meta_file.write_text(json.dumps(meta))
    with pytest.raises(ds.FormatError, match=r"scene\.json: format_version 3\.0 has major version 3; "
                                             r"this dotsim \(.*\) reads major versions 1, 2"):
        ds.read_scene(path)
    meta["format_version"] = "2.7"  # a newer minor version is read
    meta_file.write_text(json.dumps(meta))
    assert ds.read_scene(path).meta["format_version"] == "2.7"
    ds.seal_dataset(tmp_path)
    index_file = tmp_path / "index.json"
    text = index_file.read_text()
    index_file.write_text(text.replace(f'"format_version": "{ds.FORMAT_VERSION}"', '"format_version": "3.1"'))
    with pytest.raises(ds.FormatError, match=r"index\.json: format_version 3\.1 has major version 3"):
        ds.open_dataset(tmp_path)


def test_missing_index_and_empty_dataset(tmp_path):
    with pytest.raises(ds.FormatError, match=r"index\.json: missing; the directory holds no dotsim"):
        ds.open_dataset(tmp_path)
    with pytest.raises(ds.FormatError, match=r"dataset\.json: missing.*holds no scenes"):
        ds.seal_dataset(tmp_path)
    with pytest.raises(ds.FormatError, match="does not exist"):
        ds.open_dataset(tmp_path / "nope")
    write(tmp_path, 0)
    with pytest.raises(ds.FormatError, match=r"index\.json: missing; it has scene shards: seal it with "):
        ds.open_dataset(tmp_path)


def test_seal_reruns_after_more_scenes(tmp_path):
    write(tmp_path, 0)
    assert ds.seal_dataset(tmp_path).index["scene_count"] == 1
    write(tmp_path, 1)
    write(tmp_path, 2)
    assert ds.seal_dataset(tmp_path).index["scene_count"] == 3
    assert len(ds.open_dataset(tmp_path)) == 3


def test_capture_scene_with_ir_only(tmp_path):
    rng = np.random.default_rng(0)
    frames = [{"ir": rng.uniform(0, 1, (H, W))} for _ in range(4)]
    path = ds.write_scene(tmp_path, 0, make_meta(0), frames, scenes_per_shard=2, channels=("ir",))
    scene = ds.read_scene(path)
    assert [set(f) for f in scene.frames] == [{"ir"}] * 4
    with pytest.raises(ds.FormatError, match=r"\['depth'\] requested but the scene has \['ir'\]"):
        ds.read_frame(path / "frame_0.exr", channels=["depth"])
