"""`dotsim show`: a real scene written with the dataset writer, drawn, and checked pixel by pixel."""

import argparse

import cv2
import numpy as np
import pytest

from dotsim import dataset as ds
from dotsim import show
from dotsim.rig import get_preset

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
    parser = argparse.ArgumentParser()
    show.add_parser(parser.add_subparsers())
    args = parser.parse_args(["show", *map(str, argv)])
    return args.func(args)


def test_sheet_layout_and_known_pixels(tmp_path):
    scene = write_scene(tmp_path)
    out = tmp_path / "sheet.png"
    assert run_cli(scene, "-o", out, "--tile-width", 122) == 0
    sheet = cv2.imread(str(out))
    frames, title, labels = show.load_for_sheet(scene)
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
        # ambient and flood share the flood's scale: flood at 1.0 -> 255, ambient 0.1/0.4 -> 64
        assert (tile(k, "flood") == 255).all() and (tile(k, "ambient") == round(0.25 * 255)).all()
        depth = tile(k, "depth")
        assert (depth[:18, :18] == 0).all()  # the inf block (10 of 61 px -> 20 of 122) is black
        assert (depth[30:, 30:].sum(axis=2) > 0).all()
    # Depth 2, 3, 4 m over frames: turbo's low end is blue, high end red (BGR).
    near, far = tile(0, "depth")[-1, -1], tile(2, "depth")[-1, -1]
    assert near[0] > near[2] and far[2] > far[0]


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
