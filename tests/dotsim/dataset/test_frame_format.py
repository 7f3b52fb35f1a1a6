"""Format 2 frames: each channel's precision pinned against independent numbers, disparity derived
on read bit for bit, and format 1 frames (every channel stored, ZIP) still read as written."""

import hashlib
import json
from dataclasses import replace

import numpy as np
import OpenEXR
import pytest

from dotsim import dataset as ds
from dotsim.channels import STEREO_CHANNELS, rendered_channels
from dotsim.rig.presets import get_preset

RIG = get_preset("structure_core").scaled(0.05)  # 61 x 45 camera
H, W = RIG.camera.height, RIG.camera.width


def frame_inputs(rng, bits=10):
    """A frame as a generator hands it over, in float64 where it computes in float64."""
    depth = rng.uniform(0.2, 30.0, (H, W))  # beyond max_depth (20 m) too
    depth[0, :4] = np.inf
    top = 2**bits - 1
    return {
        "ir": np.rint(rng.uniform(0, 1, (H, W)) * top) / top,
        # radiance over many binades, subnormal halves included
        "ambient": np.exp(rng.uniform(np.log(1e-8), np.log(60000.0), (H, W))),
        "flood": rng.uniform(0, 5, (H, W)),
        "depth": depth,
        "visibility": rng.uniform(size=(H, W)) > 0.5,
        "edge": rng.uniform(size=(H, W)) > 0.9,
        "projector_column": np.where(np.isfinite(depth), rng.uniform(-100, 4000, (H, W)), np.nan),
    }


def meta(frames=1):
    return {"split": "train", "rig": RIG.to_dict(), "pattern": {"source": "procedural"},
            "poses": [np.eye(4).tolist()] * frames}


def expected_disparity(depth32):
    """fx * b / z in float64, stored as float32; nan without a hit or beyond max_depth."""
    z = depth32.astype(np.float64)
    with np.errstate(divide="ignore"):
        d = RIG.camera.fx * RIG.baseline / z
    return np.where(np.isfinite(z) & (z <= RIG.max_depth), d, np.nan).astype(np.float32)


# The largest error each channel may have against what the generator computed (docs/FORMAT.md):
# half floats round to 11 significant bits (relative 2^-11), and below 2^-14 to steps of 2^-24.
def half_error_bound(x):
    return np.maximum(np.abs(x) * 2.0**-11, 2.0**-25)


@pytest.mark.parametrize("bits", [10, 11])
def test_format_2_precision_of_every_channel(tmp_path, bits):
    sent = frame_inputs(np.random.default_rng(bits), bits)
    scene = ds.write_scene(tmp_path, 0, meta(), [sent])
    got = ds.read_frame(scene / "frame_0.exr")
    assert {k: v.dtype for k, v in got.items()} == {k: ds.FRAME_CHANNELS[k] for k in ds.RENDERED_CHANNELS}
    # IR: the sensor's codes come back exactly (up to 11 bits).
    top = 2**bits - 1
    assert np.array_equal(np.rint(got["ir"].astype(np.float64) * top), np.rint(sent["ir"] * top))
    # Ground truth: depth and projector column are exactly the float32 of what was computed.
    for name in ("depth", "projector_column"):
        want = sent[name].astype(np.float32)
        assert np.array_equal(got[name], want, equal_nan=True), name
    # disparity is not stored, and comes back as fx * b / z of the stored depth, bit for bit.
    assert np.array_equal(got["disparity"], expected_disparity(got["depth"]), equal_nan=True)
    assert np.isnan(got["disparity"][sent["depth"] > RIG.max_depth]).all()
    # Masks exactly.
    for name in ("visibility", "edge"):
        assert np.array_equal(got[name], sent[name].astype(np.uint8)), name
    # ambient and flood: half floats, within the documented bound, and not better than half.
    for name in ("ambient", "flood"):
        error = np.abs(got[name].astype(np.float64) - sent[name])
        assert (error <= half_error_bound(sent[name])).all(), name
        assert error.max() > 0, name
    exr = OpenEXR.File(str(scene / "frame_0.exr"), separate_channels=True)
    assert "disparity" not in exr.channels()
    assert exr.header()["dotsim_format_version"] == "2.0"  # no channel of 2.1: the bytes of 2.0
    assert json.loads(exr.header()["dotsim_rig"]) == RIG.to_dict()


def test_lone_format_2_frame_derives_disparity_from_its_header(tmp_path):
    sent = frame_inputs(np.random.default_rng(1))
    path = tmp_path / "lone.exr"
    ds.write_frame_file(path, sent, (H, W), rig=RIG.to_dict())
    got = ds.read_frame(path)  # no scene.json beside it
    assert np.array_equal(got["disparity"], expected_disparity(sent["depth"].astype(np.float32)),
                          equal_nan=True)
    assert set(ds.read_frame(path, channels=("disparity",))) == {"disparity"}


def test_a_stereo_pair_frame_is_format_2_1_and_derives_its_stereo_disparity(tmp_path):
    """ir_right and stereo_visibility stored exactly as the other IR and masks are; stereo_disparity
    derived from the stored depth and the header's rig: fx B / z (B = the second camera's x, 0.07501 m
    for Structure Core), bit for bit. The frame and its scene.json record 2.1; a lone frame of the
    same rig without the pair derives no stereo channel."""
    rng = np.random.default_rng(4)
    sent = frame_inputs(rng)
    sent["ir_right"] = np.rint(rng.uniform(0, 1, (H, W)) * 1023) / 1023
    sent["stereo_visibility"] = rng.uniform(size=(H, W)) > 0.3
    channels = rendered_channels(stereo=True)
    scene = ds.write_scene(tmp_path, 0, meta(), [sent], channels=channels)
    got = ds.read_frame(scene / "frame_0.exr")
    assert set(got) == set(channels)
    np.testing.assert_array_equal(np.rint(got["ir_right"].astype(np.float64) * 1023),
                                  np.rint(sent["ir_right"] * 1023))
    np.testing.assert_array_equal(got["stereo_visibility"], sent["stereo_visibility"].astype(np.uint8))
    z = got["depth"].astype(np.float64)
    with np.errstate(divide="ignore"):
        expected = np.where(np.isfinite(z) & (z <= RIG.max_depth), RIG.camera.fx * 0.07501 / z, np.nan)
    np.testing.assert_array_equal(got["stereo_disparity"], expected.astype(np.float32))
    exr = OpenEXR.File(str(scene / "frame_0.exr"), separate_channels=True)
    assert "stereo_disparity" not in exr.channels() and exr.header()["dotsim_format_version"] == "2.1"
    assert ds.read_scene_meta(scene)["format_version"] == "2.1"
    lone = tmp_path / "lone.exr"
    ds.write_frame_file(lone, frame_inputs(rng), (H, W), rig=RIG.to_dict())
    assert not set(ds.read_frame(lone)) & set(STEREO_CHANNELS)
    with_pair = tmp_path / "pair.exr"
    ds.write_frame_file(with_pair, sent, (H, W), channels, rig=RIG.to_dict())
    np.testing.assert_array_equal(ds.read_frame(with_pair)["stereo_disparity"], got["stereo_disparity"])


def test_stereo_channels_of_a_rig_without_a_pair_are_refused_naming_the_rig(tmp_path):
    rng = np.random.default_rng(5)
    sent = dict(frame_inputs(rng), ir_right=np.zeros((H, W)), stereo_visibility=np.zeros((H, W), bool))
    mono = replace(RIG, name="mono", second_camera_translation=None)
    with pytest.raises(ds.FormatError, match="scene 0 frame 0: channel 'stereo_disparity': stereo disparity: "
                                             "rig 'mono' has no second IR camera"):
        ds.write_scene(tmp_path, 0, dict(meta(), rig=mono.to_dict()), [sent],
                       channels=rendered_channels(stereo=True))
    assert not list(tmp_path.iterdir())  # nothing written


def test_writer_refuses_a_disparity_that_is_not_fx_b_over_depth(tmp_path):
    sent = frame_inputs(np.random.default_rng(2))
    # One from the float64 depth (before its rounding to float32) is accepted; the reader returns
    # the one derived from the stored depth.
    with np.errstate(divide="ignore"):
        own = RIG.camera.fx * RIG.baseline / sent["depth"]
    sent["disparity"] = np.where(sent["depth"] <= RIG.max_depth, own, np.nan).astype(np.float32)
    scene = ds.write_scene(tmp_path, 0, meta(), [dict(sent)])
    assert not np.array_equal(sent["disparity"], expected_disparity(sent["depth"].astype(np.float32)),
                              equal_nan=True)  # differs by the rounding of depth
    assert np.array_equal(ds.read_frame(scene / "frame_0.exr")["disparity"],
                          expected_disparity(sent["depth"].astype(np.float32)), equal_nan=True)
    first = np.unravel_index(np.flatnonzero(np.isfinite(sent["disparity"]))[0], (H, W))
    sent["disparity"][first] *= 1 + 1e-5  # beyond float32 rounding
    with pytest.raises(ds.FormatError, match=r"scene 1 frame 0: channel 'disparity' differs from what the "
                                             r"reader derives from its 'depth' channel and the rig \(fx \* "
                                             r"baseline / depth"):
        ds.write_scene(tmp_path, 1, meta(), [sent])
    with pytest.raises(ds.FormatError, match=r"'disparity' is derived from 'depth' and the rig"):
        ds.encode_frame(sent, (H, W))  # no rig to derive it with


def write_format_1_scene(scene_dir, frames):
    """A scene exactly as dotsim wrote format 1.2: ZIP, every channel stored (disparity included),
    version 1.2 in the EXR header and scene.json; built with OpenEXR and json directly."""
    scene_dir.mkdir(parents=True)
    entries = []
    for k, frame in enumerate(frames):
        pixels = {name: np.ascontiguousarray(np.asarray(a).astype(
            np.uint32 if name in ds.MASK_CHANNELS else ds.FRAME_CHANNELS[name])) for name, a in frame.items()}
        path = scene_dir / f"frame_{k}.exr"
        OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
                      "dotsim_format_version": "1.2"}, pixels).write(str(path))
        entries.append({"file": path.name, "sha256": hashlib.sha256(path.read_bytes()).hexdigest()})
    scene_meta = dict(meta(len(frames)), format_version="1.2", dotsim_version="0.1.0", scene_index=0,
                      frame_count=len(frames), channels={c: ds.FRAME_CHANNELS[c].name for c in frames[0]},
                      frames=entries)
    (scene_dir / "scene.json").write_text(json.dumps(scene_meta))


def test_format_1_scene_is_read_as_written(tmp_path):
    rng = np.random.default_rng(3)
    frames = [frame_inputs(rng) for _ in range(2)]
    for frame in frames:
        # Format 1 stored whatever disparity it was given: the reader returns that, not a derived one.
        frame["disparity"] = rng.uniform(1, 80, (H, W)).astype(np.float32)
    scene_dir = tmp_path / "shard_00000" / "scene_0000000"
    write_format_1_scene(scene_dir, frames)
    scene = ds.read_scene(scene_dir)
    assert scene.meta["format_version"] == "1.2"
    for got, sent in zip(scene.frames, frames, strict=True):
        assert set(got) == set(ds.RENDERED_CHANNELS)
        for name in ds.RENDERED_CHANNELS:
            want = np.asarray(sent[name]).astype(ds.FRAME_CHANNELS[name])
            assert got[name].dtype == ds.FRAME_CHANNELS[name], name
            assert np.array_equal(got[name], want, equal_nan=True), name
    lone = ds.read_frame(scene_dir / "frame_1.exr", channels=("disparity", "ir"), meta=None, verify=False)
    assert np.array_equal(lone["disparity"], frames[1]["disparity"])
    # A format 1 dataset seals and opens as before.
    (tmp_path / "dataset.json").write_text(json.dumps({"format_version": "1.2", "scenes_per_shard": 100}))
    ds.seal_dataset(tmp_path)
    assert ds.open_dataset(tmp_path).read_scene(0).frames[0]["disparity"].dtype == np.float32


def test_threads_do_not_change_the_bytes(tmp_path):
    rng = np.random.default_rng(4)
    frames = [frame_inputs(rng) for _ in range(3)]
    one = ds.write_scene(tmp_path / "a", 0, meta(3), frames, threads=1)
    three = ds.write_scene(tmp_path / "b", 0, meta(3), frames, threads=3)
    for name in ("frame_0.exr", "frame_1.exr", "frame_2.exr", "scene.json"):
        assert (one / name).read_bytes() == (three / name).read_bytes(), name
    # A frame's error is raised as in a loop: the scene is not written.
    frames[2]["edge"] = np.full((H, W), 3, np.uint8)
    with pytest.raises(ds.FormatError, match=r"scene 1 frame 2: mask channel 'edge'"):
        ds.write_scene(tmp_path / "a", 1, meta(3), frames, threads=3)
    assert not ds.is_scene_complete(tmp_path / "a", 1)


def test_label_and_normal_channels_are_format_2_2_labels_exact(tmp_path):
    """instance and material (UINT on disk, int32 as read) come back exactly, up to Blender's largest
    pass index and beyond float16's integers; the normals within half's rounding; the mask as a mask;
    the frame and scene.json record 2.2. A negative or fractional label is refused naming it."""
    rng = np.random.default_rng(5)
    sent = frame_inputs(rng)
    sent["instance"] = rng.integers(0, 32768, (H, W)).astype(np.int32)
    sent["material"] = rng.integers(0, 5, (H, W))
    sent["transparent_or_mirror"] = sent["material"] >= 2
    normal = rng.normal(size=(H, W, 3))
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    for k, axis in enumerate("xyz"):
        sent[f"normal_{axis}"] = normal[..., k].astype(np.float32)
    channels = rendered_channels(False, ("labels", "normals"))
    scene = ds.write_scene(tmp_path, 0, meta(), [sent], channels=channels)
    got = ds.read_frame(scene / "frame_0.exr")
    assert got["instance"].dtype == np.int32 and got["material"].dtype == np.int32
    np.testing.assert_array_equal(got["instance"], sent["instance"])
    np.testing.assert_array_equal(got["material"], sent["material"])
    np.testing.assert_array_equal(got["transparent_or_mirror"],
                                  sent["transparent_or_mirror"].astype(np.uint8))
    for axis in "xyz":
        error = np.abs(got[f"normal_{axis}"].astype(np.float64) - sent[f"normal_{axis}"])
        assert (error <= half_error_bound(sent[f"normal_{axis}"])).all()
    exr = OpenEXR.File(str(scene / "frame_0.exr"), separate_channels=True)
    assert exr.channels()["instance"].pixels.dtype == np.uint32
    assert exr.header()["dotsim_format_version"] == "2.2" == ds.read_scene_meta(scene)["format_version"]
    for bad in (-1, 0.5):
        wrong = {**sent, "instance": np.full((H, W), bad)}
        with pytest.raises(ds.FormatError, match="label channel 'instance' must hold integers"):
            ds.write_frame_file(tmp_path / "bad.exr", wrong, (H, W), channels, rig=RIG.to_dict())


def test_a_colour_cameras_image_has_its_own_shape_in_a_part_of_its_own(tmp_path):
    """rgb (format 2.3) is stored at the colour camera's size that scene.json gives, in a second part
    `colour` (rgb.R, rgb.G, rgb.B), read back as float16 (h, w, 3) within half's rounding, the IR channels
    as without it; a lone frame reads it at its own size. Refused in one line: an rgb of the IR camera's
    shape, a scene whose scene.json gives no colour camera, a frame without its part."""
    colour = (27, 40)  # not the IR camera's 45 x 61
    rng = np.random.default_rng(7)
    sent = frame_inputs(rng)
    sent["rgb"] = rng.uniform(0, 3, colour + (3,))
    channels = rendered_channels(False, ("rgb",))
    identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    intrinsics = {"width": 40, "height": 27, "fx": 30.0, "fy": 30.0, "cx": 19.5, "cy": 13.0}
    with_colour = {**meta(), "colour_camera": {"intrinsics": intrinsics, "translation": [-0.015, 0.0, 0.0],
                                               "rotation": identity}}
    scene = ds.write_scene(tmp_path / "a", 0, with_colour, [sent], channels=channels)
    got = ds.read_frame(scene / "frame_0.exr")
    assert got["rgb"].dtype == np.float16 and got["rgb"].shape == colour + (3,)
    assert (np.abs(got["rgb"].astype(np.float64) - sent["rgb"]) <= half_error_bound(sent["rgb"])).all()
    plain = ds.read_frame(ds.write_scene(tmp_path / "b", 0, meta(), [frame_inputs(np.random.default_rng(7))])
                          / "frame_0.exr")
    for name in plain:
        np.testing.assert_array_equal(got[name], plain[name])
    exr = OpenEXR.File(str(scene / "frame_0.exr"), separate_channels=True)
    assert [p.name() for p in exr.parts] == ["ir", "colour"]
    assert sorted(exr.parts[1].channels) == ["rgb.B", "rgb.G", "rgb.R"]
    assert exr.header()["dotsim_format_version"] == "2.3" == ds.read_scene_meta(scene)["format_version"]
    lone = tmp_path / "lone.exr"
    lone.write_bytes((scene / "frame_0.exr").read_bytes())
    np.testing.assert_array_equal(ds.read_frame(lone)["rgb"], got["rgb"])

    with pytest.raises(ds.FormatError, match=r"channel 'rgb' has shape \(45, 61, 3\), the colour camera's is "
                                             r"\(27, 40, 3\)"):
        ds.write_scene(tmp_path / "c", 0, with_colour, [{**sent, "rgb": np.zeros((H, W, 3))}],
                       channels=channels)
    with pytest.raises(ds.FormatError, match="channel 'rgb' is an image of the colour camera, whose size the "
                                             "scene does not give"):
        ds.write_scene(tmp_path / "d", 0, meta(), [sent], channels=channels)
    with pytest.raises(ds.FormatError, match=r"channel\(s\) \['rgb'\] of a camera whose size scene.json "
                                             "does not give"):
        ds.parse_scene_meta(scene / "scene.json", json.dumps(
            {k: v for k, v in ds.read_scene_meta(scene).items() if k != "colour_camera"}).encode())
    single = ds.encode_frame(frame_inputs(rng), (H, W), rendered_channels(False), rig=RIG.to_dict())
    (tmp_path / "single.exr").write_bytes(single)
    with pytest.raises(ds.FormatError, match=r"missing channel\(s\) \['rgb'\]"):
        ds.read_frame(tmp_path / "single.exr", channels=("rgb",))
