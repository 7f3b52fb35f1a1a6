"""`dotsim view --save`: the recording read back with Rerun's own dataframe API, entity by entity.

The scene is written with the dataset writer (oracle frames of dotsim/oracle_dataset.py) at four
distinct poses; predictions are files in `dotsim infer`'s format (dotsim.prediction_file.write_prediction).
"""

import sys

import numpy as np
import pytest

from commands import cli, view
from dotsim import dataset as ds
from dotsim.channels import rendered_channels
from dotsim.oracle_dataset import random_depth, synthetic_frame
from dotsim.patterns import generate_dot_pattern
from dotsim.prediction_file import write_prediction
from dotsim.rig.presets import get_preset
from tests.capture_inputs import write_on_off_frames
from tests.output_folders import assert_one_line_error

rr = pytest.importorskip("rerun")  # the dev extra installs it (dotsim[view])

RIG = get_preset("structure_core").scaled(0.06)  # 73 x 54 camera px
H, W = RIG.camera.height, RIG.camera.width


def pose(k):
    p = np.eye(4)
    p[:3, 3] = [0.1 * k, -0.05 * k, 1.2]
    return p


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("ds")
    dots = generate_dot_pattern(RIG.projector.width, RIG.projector.height, seed=0)
    rng = np.random.default_rng(3)
    frames = [synthetic_frame(random_depth(RIG, rng), RIG, np.asarray(dots.image, np.float64), rng)
              for _ in range(4)]
    meta = {"split": "test", "rig": RIG.to_dict(), "pattern": {"sha256": dots.sha256},
            "poses": [pose(k).tolist() for k in range(4)]}
    path = ds.write_scene(root, 5, meta, frames)
    ds.seal_dataset(root)
    return root, path


def component(rrd, entity, name, static=False):
    """{frame: pyarrow value} of one component of one entity (static: {None: value})."""
    view = rr.dataframe.load_recording(str(rrd)).view(index="frame",
                                                      contents={entity: [f"rerun.components.{name}"]})
    table = (view.select_static() if static else view.select()).read_all()
    column = table.column(f"{entity}:{name}")
    frames = [None] * table.num_rows if static else table.column("frame").to_pylist()
    return {f: column[i].values for i, f in enumerate(frames) if column[i].is_valid}


def image(rrd, entity, frame, dtype):
    """The (H, W) pixels of an image entity at a frame, from its raw buffer."""
    raw = np.asarray(component(rrd, entity, "ImageBuffer")[frame].flatten(), np.uint8).tobytes()
    return np.frombuffer(raw, dtype).reshape(H, W)


def array(value, dtype=np.float32, width=None):
    flat = np.asarray(value.flatten() if hasattr(value, "flatten") else value, dtype)
    return flat if width is None else flat.reshape(-1, width)


def test_recording_holds_passes_clouds_and_frusta(scene, tmp_path, capsys):
    root, path = scene
    out = tmp_path / "scene.rrd"
    assert cli.main(["view", str(root), "--scene", "5", "--save", str(out)]) == 0
    assert "points per cloud" in capsys.readouterr().out
    entities = {c.entity_path for c in rr.dataframe.load_recording(str(out)).schema().component_columns()}
    # the passes under the current frame's camera (its Pinhole): drawn in its frustum, depth back-projected
    expected = {f"/world/camera/{p}" for p in ("ir", "ambient", "flood", "depth", "visibility", "edge")}
    for k in range(4):
        expected |= {f"/world/pose_{k}", f"/world/pose_{k}/camera", f"/world/pose_{k}/projector",
                     f"/world/pose_{k}/ground_truth"}
    assert expected <= entities and not any("prediction" in e or "error" in e for e in entities)
    meta = ds.read_scene_meta(path)
    for k in range(4):
        frame = ds.read_frame(path / ds.frame_name(k))
        fmt = component(out, "/world/camera/ir", "ImageFormat")[k][0].as_py()
        assert (fmt["width"], fmt["height"]) == (W, H)
        ir = image(out, "/world/camera/ir", k, np.float32)
        assert np.array_equal(ir, frame["ir"].astype(np.float32))  # the IR sequence as stored
        assert np.array_equal(image(out, "/world/camera/visibility", k, np.uint8), frame["visibility"] * 255)
        depth_image = image(out, "/world/camera/depth", k, np.float32)
        assert np.array_equal(depth_image, np.where(np.isfinite(frame["depth"]), frame["depth"], 0))
        # the camera those images hang under moves with the frame: its pose at frame k is pose k
        moved = array(component(out, "/world/camera", "Translation3D")[k])
        np.testing.assert_allclose(moved, np.asarray(meta["poses"][k])[:3, 3], rtol=1e-6)
        # the cloud: every pixel with a hit, backprojected by hand in the camera (rig) frame
        points = array(component(out, f"/world/pose_{k}/ground_truth", "Position3D")[k], width=3)
        depth = frame["depth"].astype(np.float64)
        v, u = np.nonzero(np.isfinite(depth))
        cam = RIG.camera
        by_hand = np.stack([(u - cam.cx) * depth[v, u] / cam.fx, (v - cam.cy) * depth[v, u] / cam.fy,
                            depth[v, u]], axis=1)
        assert points.shape == by_hand.shape
        np.testing.assert_allclose(points, by_hand, rtol=1e-5, atol=1e-6)
        # the rig at the scene's pose, the projector at the rig's translation, both frusta sized
        translation = array(component(out, f"/world/pose_{k}", "Translation3D", static=True)[None])
        np.testing.assert_allclose(translation, np.asarray(meta["poses"][k])[:3, 3], rtol=1e-6)
        projector = array(component(out, f"/world/pose_{k}/projector", "Translation3D", static=True)[None])
        np.testing.assert_allclose(projector, RIG.projector_translation, rtol=1e-6)
        for name, intr in (("camera", RIG.camera), ("projector", RIG.projector)):
            resolution = array(component(out, f"/world/pose_{k}/{name}", "Resolution", static=True)[None])
            assert resolution.tolist() == [intr.width, intr.height]
            pinhole = component(out, f"/world/pose_{k}/{name}", "PinholeProjection", static=True)
            k_matrix = array(pinhole[None])
            np.testing.assert_allclose(k_matrix.reshape(3, 3).T, intr.K, rtol=1e-6)  # stored column-major
    current = array(component(out, "/world/camera", "PinholeProjection", static=True)[None])
    np.testing.assert_allclose(current.reshape(3, 3).T, RIG.camera.K, rtol=1e-6)


def test_predictions_beside_the_truth_and_one_frame(scene, tmp_path):
    root, path = scene
    preds = tmp_path / "pred"
    preds.mkdir()
    frame = ds.read_frame(path / ds.frame_name(2))
    disparity = frame["disparity"] + 1.0  # 1 px off everywhere
    disparity[0, :5] = 0.01  # and hundreds of metres away: beyond the rig's range, not drawn
    depth = RIG.camera.fx * RIG.baseline / disparity
    write_prediction(preds / "scene_0000005_frame_2.exr", {"disparity": disparity, "depth": depth},
                     {"checkpoint": "c.pt", "input": str(path / "frame_2.exr"), "precision": "float32"})
    out = tmp_path / "pred.rrd"
    assert cli.main(["view", str(path), "--frame", "2", "--predictions", str(preds), "--save", str(out)]) == 0
    entities = {c.entity_path for c in rr.dataframe.load_recording(str(out)).schema().component_columns()}
    assert "/world/pose_2/prediction" in entities and "/world/camera/error" in entities
    assert not any(e.startswith("/world/pose_0") for e in entities)  # --frame 2 only
    predicted = array(component(out, "/world/pose_2/prediction", "Position3D")[2], width=3)
    assert len(predicted) == int(np.isfinite(depth).sum()) - 5 and (depth[0, :5] > RIG.max_depth).all()
    fmt = component(out, "/world/camera/error", "ImageFormat")[2][0].as_py()
    assert (fmt["width"], fmt["height"]) == (W, H)
    # any subset of the frames: all four viewed with the prediction of frame 2 alone
    every = tmp_path / "every.rrd"
    assert cli.main(["view", str(path), "--predictions", str(preds), "--save", str(every)]) == 0
    clouds = {e for e in {c.entity_path for c in rr.dataframe.load_recording(str(every)).schema()
                          .component_columns()} if e.endswith("/prediction")}
    assert clouds == {"/world/pose_2/prediction"}
    error = component(every, "/world/camera/error", "ImageBuffer")
    assert {k for k, value in error.items() if len(value)} == {2}  # cleared (empty) on frames 0, 1 and 3
    # a folder with no prediction for the scene's frames is one line
    assert cli.main(["view", str(path), "--frame", "1", "--predictions", str(preds), "--save", str(out)]) == 1
    assert cli.main(["view", str(path), "--save", str(tmp_path / "x.png")]) == 1
    assert not list(tmp_path.glob(".tmp-*"))


def test_the_logged_channels_are_the_declared_grey_ones_masks_and_depth():
    assert view.VIEWED == ("ir", "ambient", "flood", "depth", "visibility", "edge", "device_depth",
                           "ir_right", "stereo_visibility", "instance", "material", "transparent_or_mirror",
                           "normal_x")


def test_a_stereo_pair_adds_the_right_ir_its_mask_and_the_right_frustum(scene, tmp_path):
    """A scene of the pair (the oracle frames with a right IR and a mask beside them): its right IR as
    stored, the mask 0 / 255, the right camera's frustum at the rig's second camera (Structure Core:
    0.07501 m along x); a scene without the pair has neither."""
    root = tmp_path / "pair"
    rng = np.random.default_rng(8)
    frames = []
    for frame in (ds.read_frame(scene[1] / ds.frame_name(k)) for k in range(4)):
        frame.update(ir_right=rng.uniform(0, 1, (H, W)), stereo_visibility=rng.uniform(size=(H, W)) > 0.5)
        frames.append(frame)
    meta = {"split": "test", "rig": RIG.to_dict(), "pattern": {"sha256": "0" * 64},
            "poses": [pose(k).tolist() for k in range(4)]}
    path = ds.write_scene(root, 0, meta, frames, channels=rendered_channels(stereo=True))
    out = tmp_path / "pair.rrd"
    assert cli.main(["view", str(path), "--save", str(out)]) == 0
    entities = {c.entity_path for c in rr.dataframe.load_recording(str(out)).schema().component_columns()}
    assert {"/world/camera/ir_right", "/world/camera/stereo_visibility",
            "/world/pose_3/camera_right"} <= entities
    stored = ds.read_frame(path / ds.frame_name(1))
    assert np.array_equal(image(out, "/world/camera/ir_right", 1, np.float32),
                          stored["ir_right"].astype(np.float32))
    assert np.array_equal(image(out, "/world/camera/stereo_visibility", 1, np.uint8),
                          stored["stereo_visibility"] * 255)
    right = array(component(out, "/world/pose_3/camera_right", "Translation3D", static=True)[None])
    np.testing.assert_allclose(right, [0.07501, 0.0, 0.0], rtol=1e-6)
    mono = tmp_path / "mono.rrd"
    assert cli.main(["view", str(scene[1]), "--save", str(mono)]) == 0
    entities = {c.entity_path for c in rr.dataframe.load_recording(str(mono)).schema().component_columns()}
    assert not any("right" in entity for entity in entities)


def test_missing_rerun_is_one_clear_line(scene, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "rerun", None)
    assert cli.main(["view", str(scene[0]), "--save", "x.rrd"]) == 1
    assert 'dotsim view needs rerun-sdk: pip install "dotsim[view]"' in capsys.readouterr().err


def test_without_save_it_spawns_the_viewer(scene, monkeypatch, capsys, tmp_path):
    spawned = []
    monkeypatch.setattr(rr.RecordingStream, "spawn", lambda self, **kw: spawned.append(self))  # no GUI here
    monkeypatch.chdir(tmp_path)
    assert cli.main(["view", str(scene[0]), "--frame", "1"]) == 0
    assert len(spawned) == 1 and "sent to the Rerun viewer" in capsys.readouterr().out
    assert not list(tmp_path.iterdir())  # nothing written



def test_labels_are_segmentation_images_and_normals_one_rgb_image():
    rr = pytest.importorskip("rerun")
    frame = {"instance": np.array([[0, 7]], np.int32), "normal_x": np.array([[0.0, np.nan]]),
             "normal_y": np.zeros((1, 2)), "normal_z": np.array([[-1.0, 0.0]])}
    assert isinstance(view.viewer_image(rr, frame, "instance"), rr.SegmentationImage)
    assert isinstance(view.viewer_image(rr, frame, "normal_x"), rr.Image)


def test_a_capture_without_depth_shows_its_passes(tmp_path, capsys):
    """Issue 45 item 3: a `capture import` dataset has no depth; view showed a KeyError traceback."""
    rig = get_preset("structure_core").scaled(0.1)
    write_on_off_frames(tmp_path, (rig.camera.height, rig.camera.width), seed=0)
    data = tmp_path / "captured"
    assert cli.main(["capture", "import", "--on", str(tmp_path / "on"), "--off", str(tmp_path / "off"),
                     "--scale", "0.1", "--frames-per-scene", "2", "--out", str(data), "--no-progress"]) == 0
    capsys.readouterr()
    out = tmp_path / "cap.rrd"
    assert cli.main(["view", str(data), "--save", str(out)]) == 0
    assert "no depth" in capsys.readouterr().out
    entities = {c.entity_path for c in rr.dataframe.load_recording(str(out)).schema().component_columns()}
    assert "/world/camera/ir" in entities and not any(e.endswith("ground_truth") for e in entities)


def test_predictions_of_another_dataset_are_refused(scene, tmp_path, capsys):
    """Issue 45 item 17: a prediction whose header names another input file is not drawn as this
    frame's, and one of another camera size neither."""
    root, path = scene
    other = tmp_path / "other_frame.exr"
    other.write_bytes((path / "frame_2.exr").read_bytes())  # an existing file that is not this frame
    frame = ds.read_frame(path / ds.frame_name(2))
    preds = tmp_path / "pred"
    preds.mkdir()
    channels = {"disparity": frame["disparity"], "depth": frame["depth"]}
    write_prediction(preds / "scene_0000005_frame_2.exr", channels,
                     {"checkpoint": "c.pt", "input": str(other), "precision": "float32"})
    argv = ["view", str(path), "--frame", "2", "--predictions", str(preds), "--save", str(tmp_path / "a.rrd")]
    capsys.readouterr()
    assert cli.main(argv) == 1
    assert_one_line_error(capsys.readouterr().err, f"predicted from {other}, not from {path / 'frame_2.exr'}")
    small = {k: v[:-2, :-2] for k, v in channels.items()}
    write_prediction(preds / "scene_0000005_frame_2.exr", small,
                     {"checkpoint": "c.pt", "input": str(path / "frame_2.exr"), "precision": "float32"})
    assert cli.main(argv) == 1
    assert_one_line_error(capsys.readouterr().err, f"{W - 2} x {H - 2} px, not the scene's camera")
    assert not (tmp_path / "a.rrd").exists()
