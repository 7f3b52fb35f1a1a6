"""`dotsim show`: a real scene written with the dataset writer, drawn, and checked pixel by pixel."""

import cv2
import numpy as np
import pytest

from commands import cli, show
from dotsim import dataset as ds
from dotsim.channels import SWITCHES, rendered_channels
from dotsim.rig.presets import get_preset

RIG = get_preset("structure_core").scaled(0.05)  # 61 x 45
H, W = RIG.camera.height, RIG.camera.width


def constant_frame(k):
    depth = np.full((H, W), 2.0 + k, np.float32)
    depth[:10, :10] = np.inf  # no hit: must render black
    return {"ir": np.full((H, W), 0.5), "ambient": np.full((H, W), 0.1), "flood": np.full((H, W), 0.4),
            "depth": depth, "visibility": np.ones((H, W), bool), "edge": np.zeros((H, W), bool),
            "projector_column": np.full((H, W), 100.0 + k)}  # disparity: derived from depth on read


def write_scene(root, index=0):
    meta = {"split": "test", "rig": RIG.to_dict(), "pattern": {"sha256": "0" * 64},
            "poses": [np.eye(4).tolist()] * 3}
    return ds.write_scene(root, index, meta, [constant_frame(k) for k in range(3)], scenes_per_shard=2)


def run_cli(*argv):
    return cli.main(["show", *map(str, argv)])


def test_sheet_layout_and_known_pixels(tmp_path):
    scene = write_scene(tmp_path)
    out = tmp_path / "sheet.png"
    assert run_cli(scene, "-o", out, "--tile-width", 122) == 0
    sheet = cv2.imread(str(out))
    frames, title, labels, meanings = show.load_for_sheet(scene)
    assert meanings == {}
    drawn, layout = show.contact_sheet(frames, title, 122, labels)
    assert np.array_equal(sheet, drawn)  # the PNG holds exactly the drawn sheet
    tile_w, tile_h = layout.tile_size
    assert (tile_w, tile_h) == (122, round(122 * H / W)) == (122, 90)
    assert sheet.shape[1] == show.LABEL_WIDTH + 8 * (tile_w + show.GAP) + show.GAP
    assert len(layout.tiles) == 3 * 8

    def tile(k, name):
        x, y, w, h = layout.tiles[(k, name)]
        return sheet[y:y + h, x:x + w].astype(int)

    for k in range(3):
        assert (tile(k, "visibility") == 255).all()  # mask of ones: white
        assert (tile(k, "edge") == 0).all()  # mask of zeros: black
        assert (tile(k, "ir") == round(0.5 * 255)).all()  # IR is shown on its 0..1 full scale
        # ambient and flood each on its own scale (its 99th percentile): both constant -> white
        assert (tile(k, "flood") == 255).all() and (tile(k, "ambient") == 255).all()
        depth = tile(k, "depth")
        assert (depth[:18, :18] == 0).all()  # the inf block (10 of 61 px -> 20 of 122) is black
        assert (depth[30:, 30:].sum(axis=2) > 0).all()
    # Depth 2, 3, 4 m over frames: turbo's low end is blue, high end red (BGR).
    near, far = tile(0, "depth")[-1, -1], tile(2, "depth")[-1, -1]
    assert near[0] > near[2] and far[2] > far[0]


def test_the_columns_are_the_declared_channels_in_their_order():
    # the normals are one column, that of normal_x
    assert set(show.COLUMNS) == set(rendered_channels(True, tuple(SWITCHES))) - {"normal_y", "normal_z"}
    assert show.COLUMNS.index("depth") < show.COLUMNS.index("device_depth") < show.COLUMNS.index("ir_right")


def test_labels_get_a_colour_each_and_normals_one_rgb_tile(tmp_path):
    """instance: 0 (the room) black, each object a colour of its own, the same in every frame;
    material likewise; the normals (0, 0, -1) facing the camera drawn as (n + 1) / 2: RGB (128, 128, 0),
    black where there is none."""
    instance = np.zeros((H, W), np.int32)
    instance[:, 20:40], instance[:, 40:] = 3, 9
    normal_z = np.full((H, W), -1.0, np.float32)
    normal_z[:10, :10] = np.nan
    material = np.where(instance == 9, 3, np.minimum(instance, 1))
    frames = [dict(constant_frame(k), instance=instance, material=material,
                   transparent_or_mirror=instance == 9, normal_x=np.zeros((H, W)),
                   normal_y=np.zeros((H, W)), normal_z=normal_z) for k in range(2)]
    meta = {"split": "test", "rig": RIG.to_dict(), "pattern": {"sha256": "0" * 64},
            "poses": [np.eye(4).tolist()] * 2}
    channels = rendered_channels(False, ("labels", "normals"))
    scene = ds.write_scene(tmp_path, 0, meta, frames, channels=channels)
    loaded, title, labels, meanings = show.load_for_sheet(scene)
    sheet, layout = show.contact_sheet(loaded, title, 122, labels, meanings)
    assert [name for k, name in layout.tiles if k == 0][-4:] == ["instance", "material",
                                                               "transparent_or_mirror", "normal_x"]

    def tile(k, name):
        x, y, w, h = layout.tiles[(k, name)]
        return sheet[y:y + h, x:x + w].astype(int)

    room, three, nine = (tile(1, "instance")[-1, 2 * c] for c in (5, 30, 50))
    assert room.tolist() == [0, 0, 0] and three.sum() > 200 and nine.sum() > 200
    assert (three != nine).any() and (tile(0, "instance") == tile(1, "instance")).all()
    assert (tile(0, "material")[-1, 60] != tile(0, "material")[-1, 100]).any()  # classes 1 and 3
    normals = tile(0, "normal_x")
    assert normals[0, 0].tolist() == [0, 0, 0] and normals[-1, -1].tolist() == [0, 128, 128]  # BGR


def test_a_devices_depth_is_colour_mapped_black_where_it_gave_none():
    """The device's depth (a recording's, or a render's with [device_depth] on): metres on the turbo
    map, black where it reported none (NaN), like ground truth where nothing is hit."""
    frames = []
    for k in range(3):
        device = np.full((H, W), 2.0 + k, np.float32)
        device[:, :12] = np.nan  # a left band without depth
        frames.append(dict(constant_frame(k), device_depth=device))
    drawn, layout = show.contact_sheet(frames, "device", 122)
    x, y, w, h = layout.tiles[(0, "device_depth")]
    tile = drawn[y:y + h, x:x + w].astype(int)
    assert (tile[:, :20] == 0).all() and (tile[:, 30:].sum(axis=2) > 0).all()


def test_a_stereo_pair_adds_its_three_columns(tmp_path):
    """The right IR on the sensor's full scale, the stereo mask white where set, the stereo disparity
    (fx B / z, derived on read) colour-mapped in camera px: Structure Core's pair, B = 0.07501 m."""
    frames = [dict(constant_frame(k), ir_right=np.full((H, W), 0.25),
                   stereo_visibility=np.eye(H, W, dtype=bool)) for k in range(3)]
    meta = {"split": "test", "rig": RIG.to_dict(), "pattern": {"sha256": "0" * 64},
            "poses": [np.eye(4).tolist()] * 3}
    scene = ds.write_scene(tmp_path, 0, meta, frames, scenes_per_shard=2,
                           channels=rendered_channels(stereo=True))
    loaded, title, labels, meanings = show.load_for_sheet(scene)
    sheet, layout = show.contact_sheet(loaded, title, 122, labels, meanings)
    assert len(layout.tiles) == 3 * 11
    assert [name for k, name in layout.tiles if k == 0][-3:] == ["ir_right", "stereo_visibility",
                                                               "stereo_disparity"]

    def tile(k, name):
        x, y, w, h = layout.tiles[(k, name)]
        return sheet[y:y + h, x:x + w].astype(int)

    assert (tile(1, "ir_right") == round(0.25 * 255)).all()
    mask = tile(0, "stereo_visibility")[..., 0]
    assert mask[0, 0] == 255 and mask[-1, 0] == 0  # the diagonal, drawn at twice the size
    # 2, 3, 4 m: the nearest frame has the largest disparity, the red end of turbo (BGR)
    near, far = tile(0, "stereo_disparity")[-1, -1], tile(2, "stereo_disparity")[-1, -1]
    assert near[2] > near[0] and far[0] > far[2]
    np.testing.assert_allclose(loaded[0]["stereo_disparity"][20, 20], RIG.camera.fx * 0.07501 / 2.0,
                               rtol=1e-6)


def test_show_frame_file_and_dataset_and_errors(tmp_path, capsys):
    write_scene(tmp_path, 0)
    write_scene(tmp_path, 3)
    out = tmp_path / "frame.png"
    frame = tmp_path / "shard_00000" / "scene_0000000" / "frame_1.exr"
    assert run_cli(frame, "-o", out) == 0
    assert cv2.imread(str(out)).shape[1] == show.LABEL_WIDTH + 8 * (320 + show.GAP) + show.GAP
    assert run_cli(tmp_path, "--scene", 3, "-o", out) == 0
    assert "3 frame(s) x 8 pass(es)" in capsys.readouterr().out
    assert run_cli(tmp_path, "--scene", 7, "-o", out) == 1
    assert "no scene 7; it has scenes 0..3 (2 in all)" in capsys.readouterr().err
    assert run_cli(tmp_path / "empty", "-o", out) == 1
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.startswith("dotsim show: error: ")
    assert "no such file or directory" in captured.err
    assert run_cli(frame, "-o", tmp_path / "sheet.bmpx") == 1
    assert not list(tmp_path.glob(".tmp-*"))


def test_contact_sheet_rejects_empty():
    with pytest.raises(ValueError, match="at least one frame"):
        show.contact_sheet([], "t")
    with pytest.raises(ValueError, match="tile width must be at least 16 px, got 0"):
        show.contact_sheet([constant_frame(0)], "t", tile_width=0)


def test_each_grey_pass_has_its_own_scale_written_above_it(tmp_path):
    frames = [constant_frame(0)]
    rng = np.random.default_rng(0)
    frames[0]["ambient"] = rng.uniform(0, 5, (H, W))  # ambient peaks near 5, flood near 266
    frames[0]["flood"] = rng.uniform(0, 266, (H, W))
    scales = {name: show._grey_scale(frames, name) for name in ("ambient", "flood")}
    for name, scale in scales.items():  # independently: the 99th percentile of the pass itself
        assert scale == pytest.approx(np.percentile(frames[0][name], 99))
    assert show.scale_caption("ambient", scales["ambient"]) == f"sqrt, white = {scales['ambient']:.4g}"
    assert show.scale_caption("ambient", 0.0) == "0 everywhere (no light)"
    sheet, layout = show.contact_sheet(frames, "t", 122)
    x, y, w, h = layout.tiles[(0, "ambient")]
    ambient = sheet[y:y + h, x:x + w].astype(float)
    assert ambient.mean() > 100  # not black: half of its own p99 on average
    header = sheet[y - 3 * show.LINE:y, x:x + w]
    assert (header.max(axis=2) > 150).any()  # the title, meaning and scale lines are drawn


def test_overview_grid_of_the_ir_of_many_scenes(tmp_path, capsys):
    for index in range(5):
        write_scene(tmp_path, index)
    out = tmp_path / "overview.png"
    assert run_cli(tmp_path, "--overview", "--scenes", 4, "--tile-width", 100, "-o", out) == 0
    assert "IR of 4 scene(s)" in capsys.readouterr().out
    tiles, title = show.load_overview(tmp_path, frame=1, max_scenes=4)
    assert [label for label, _ in tiles] == [f"scene {k} (test)" for k in range(4)]
    assert "4 of 5 scene(s)" in title
    sheet, where = show.overview_sheet(tiles, title, 100, columns=3)
    assert len(where) == 4 and where["scene 3 (test)"][1] > where["scene 0 (test)"][1]  # second row
    x, y, w, h = where["scene 2 (test)"]
    assert (sheet[y:y + h, x:x + w] == round(0.5 * 255)).all()  # IR 0.5 of full scale
    assert run_cli(tmp_path, "--overview", "--frame", 9, "-o", out) == 1
    assert "no frame 9; it has 3" in capsys.readouterr().err


def test_ground_truth_point_cloud_ply(tmp_path, capsys):
    import trimesh

    scene = write_scene(tmp_path, 0)
    out = tmp_path / "gt.ply"
    assert run_cli(tmp_path, "--ply", out, "--frame", 2) == 0
    assert f"{H * W - 100} ground-truth points" in capsys.readouterr().out
    cloud = trimesh.load(out)
    depth = constant_frame(2)["depth"]
    v, u = np.nonzero(np.isfinite(depth))  # the 10 x 10 block without a hit has no points
    cam = RIG.camera  # pinhole by hand: x = (u - cx) z / fx
    expected = np.stack([(u - cam.cx) * depth[v, u] / cam.fx, (v - cam.cy) * depth[v, u] / cam.fy,
                         depth[v, u]], axis=1)
    np.testing.assert_allclose(cloud.vertices, expected, rtol=1e-6)
    assert (cloud.colors[:, :3] == 255).all()  # constant IR: its own 99.5th percentile, white
    assert run_cli(scene / "frame_0.exr", "--ply", out) == 1
    assert "--ply needs the scene's rig" in capsys.readouterr().err


def test_an_infer_output_is_labelled_as_predictions(tmp_path):
    """A file `dotsim infer` writes (dotsim.prediction_file, the header naming checkpoint and input): its
    columns say "predicted", not "ground truth", and the title says whose prediction it is."""
    from dotsim.prediction_file import write_prediction

    depth = constant_frame(0)["depth"]
    disparity = RIG.camera.fx * RIG.baseline / depth
    path = tmp_path / "scene_0000000_frame_0.exr"
    write_prediction(path, {"disparity": disparity, "depth": depth},
                     {"checkpoint": "/runs/tiny/checkpoint.pt", "input": "/data/frame_0.exr",
                      "precision": "float32"})
    out = tmp_path / "pred.png"
    assert run_cli(path, "-o", out, "--tile-width", 122) == 0
    frames, title, labels, meanings = show.load_for_sheet(path)
    assert meanings == {"depth": show.PREDICTED, "disparity": show.PREDICTED}
    assert title.startswith("scene_0000000_frame_0.exr  (61 x 45): PREDICTED by checkpoint.pt from "
                            "frame_0.exr")
    sheet = cv2.imread(str(out))
    predicted, layout = show.contact_sheet(frames, title, 122, labels, meanings)
    as_truth, _ = show.contact_sheet(frames, title, 122, labels)
    assert np.array_equal(sheet, predicted)
    x, _, w, _ = layout.tiles[(0, "depth")]
    row = np.s_[2 * show.LINE:3 * show.LINE + 4]  # the meaning under each column's title, descenders too
    assert not np.array_equal(predicted[row][:, x:x + w], as_truth[row][:, x:x + w])
    others = predicted.copy()
    others[row] = as_truth[row]
    assert np.array_equal(others, as_truth)  # only the meaning row differs
    # a dataset frame stays ground truth
    scene = write_scene(tmp_path / "data")
    assert show.load_for_sheet(scene / "frame_0.exr")[3] == {}
