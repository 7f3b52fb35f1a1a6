"""`dotsim stats` on frames with known content: two fronto-parallel planes (0.5 m and 3 m), a known
visible region and edge band; every figure is computed here by hand from that layout."""

import json

import cv2
import numpy as np
import pytest

from commands.cli import main as dotsim_main
from commands.stats import dataset_stats
from dotsim.dataset import seal_dataset, write_scene
from dotsim.frame_source import open_source
from dotsim.oracle_dataset import synthetic_frame
from dotsim.patterns import generate_dot_pattern
from dotsim.rig.presets import get_preset

NEAR, FAR = 0.5, 3.0


def known_frame(rig, pattern):
    h, w = rig.camera.height, rig.camera.width
    depth = np.full((h, w), NEAR)
    depth[:, w // 2 :] = FAR
    depth[-1] = np.inf  # nothing hit: not valid
    frame = synthetic_frame(depth, rig, pattern, np.random.default_rng(0), noise=0.0)
    visibility = np.zeros((h, w), np.uint8)
    visibility[:, : w // 2] = 1
    visibility[: h // 2, w // 2 :] = 1
    visibility[-1] = 0
    edge = np.zeros((h, w), np.uint8)
    edge[:, w // 2 - 1 : w // 2 + 1] = 1
    frame.update(depth=depth.astype(np.float32), visibility=visibility, edge=edge)
    return frame


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("stats")
    rig = get_preset("structure_core").scaled(0.1)
    dots = generate_dot_pattern(rig.projector.width, rig.projector.height, seed=0)
    dots.save_png(root / "pattern.png")
    frame = known_frame(rig, np.asarray(dots.image, np.float64))
    meta = {"split": "train", "seed": 0, "rig": rig.to_dict(),
            "pattern": {"source": dots.source, "sha256": dots.sha256, "width": rig.projector.width,
                        "height": rig.projector.height, "params": dots.params},
            "poses": [np.eye(4).tolist()] * 2,
            "render": {"kind": "known content (tests/commands/test_stats.py)"}}
    write_scene(root, 0, meta, [frame, frame], scenes_per_shard=2)
    seal_dataset(root)
    return root, rig


def test_shares_histograms_and_coverage(dataset):
    root, rig = dataset
    s = dataset_stats(open_source(root, "all")).summary()
    h, w = rig.camera.height, rig.camera.width
    near_visible, far_visible = (h - 1) * (w // 2), (h // 2) * (w - w // 2)
    visible = near_visible + far_visible
    assert s["frames"] == 2 and s["pixels"] == 2 * h * w
    assert s["share_valid_depth"] == pytest.approx((h - 1) / h)
    assert s["share_visible"] == pytest.approx(visible / (h * w))
    assert s["share_edge"] == pytest.approx(2 / w)
    assert s["share_edge_of_visible"] == pytest.approx((h - 1 + h // 2) / visible)
    assert s["visible"]["share_beyond_1m"] == pytest.approx(far_visible / visible)
    assert s["visible"]["share_beyond_2m"] == pytest.approx(far_visible / visible)
    assert s["valid"]["share_beyond_2m"] == pytest.approx(0.5)
    assert abs(s["visible"]["median_m"] - NEAR) < 0.011  # most visible pixels are on the near plane
    hist = np.array(s["histograms"]["depth_visible"])
    assert hist.sum() == 2 * visible
    assert hist[int(NEAR / 0.01)] == 2 * near_visible and hist[int(FAR / 0.01)] == 2 * far_visible
    disparity = np.array(s["histograms"]["disparity_visible"])
    near_d = rig.camera.fx * rig.baseline / NEAR
    assert disparity[int(near_d / 0.5)] == 2 * near_visible
    # coverage, by hand for this rectified rig: xp = fxp ((u - cx) / fx - b / z) + cxp, yp likewise
    cam, proj = rig.camera, rig.projector
    u = np.arange(w)
    lit_columns = set()
    for z, us in ((NEAR, u[: w // 2]), (FAR, u[w // 2 :])):
        xp = np.rint(proj.fx * ((us - cam.cx) / cam.fx - rig.baseline / z) + proj.cx)
        lit_columns |= {int(x) for x in xp if 0 <= x < proj.width}
    v = np.arange(h - 1)
    lit_rows = {int(y) for y in np.rint(proj.fy * (v - cam.cy) / cam.fy + proj.cy) if 0 <= y < proj.height}
    cov = s["pattern_coverage"]
    assert cov["share_columns_lit"] == pytest.approx(len(lit_columns) / proj.width)
    assert cov["share_rows_lit"] == pytest.approx(len(lit_rows) / proj.height)
    assert np.sum(cov["region_lit_pixels"]) <= 2 * visible
    # Which of the 8 x 8 projector regions the camera can see at all (0.2 m to 20 m), by hand: rows
    # yp = 2 (v - 44.5) + 153 span 64..242 -> region rows 1..6; columns xp = 2 (u - 60.5) + 153 - 223 b / z
    # span -39 (0.2 m) .. 273 (20 m) -> region columns 0..7. Only those can be "barely shown".
    assert cov["regions_in_camera_view"] == 6 * 8
    assert cov["regions_barely_shown"] and all(1 <= r <= 6 for r, _ in cov["regions_barely_shown"])


def test_cli_writes_png_and_json(dataset, tmp_path, capsys):
    root, _ = dataset
    png = tmp_path / "s.png"
    assert dotsim_main(["stats", str(root), "-o", str(png)]) == 0
    assert "beyond 1 m" in capsys.readouterr().out
    assert cv2.imread(str(png)) is not None
    saved = json.loads(png.with_suffix(".json").read_text())
    assert saved["frames"] == 2 and saved["split"] == "all" and saved["visible"]["share_beyond_1m"] > 0
    assert dotsim_main(["stats", str(root), "--split", "test", "-o", str(png)]) == 1
    assert "no scenes with split 'test'" in capsys.readouterr().err


def test_nothing_visible_is_said_and_both_files_are_written(tmp_path, capsys):
    """Issue 45 item 4: frames with no visible pixel gave a NaN median, a traceback from the JSON
    writer, and stats.png without stats.json; now both are written (medians null) and stderr says
    that there is nothing visible."""
    rig = get_preset("structure_core").scaled(0.1)
    dots = generate_dot_pattern(rig.projector.width, rig.projector.height, seed=0)
    frame = known_frame(rig, np.asarray(dots.image, np.float64))
    frame["visibility"][:] = 0
    root = tmp_path / "dark"
    write_scene(root, 0, {"split": "train", "rig": rig.to_dict(), "pattern": {"sha256": dots.sha256},
                          "poses": [np.eye(4).tolist()]}, [frame])
    seal_dataset(root)
    out = tmp_path / "stats.png"
    assert dotsim_main(["stats", str(root), "-o", str(out)]) == 0
    captured = capsys.readouterr()
    assert "no pixel of the 1 frame(s) is visible" in captured.err and "Traceback" not in captured.err
    summary = json.loads(out.with_suffix(".json").read_text())
    assert summary["share_visible"] == 0 and summary["visible"]["median_m"] is None
    assert summary["visible_disparity_px"] == {"median": None, "max": None}
    assert NEAR <= summary["valid"]["median_m"] <= FAR  # the depth is there, only nothing is visible
    assert cv2.imread(str(out)) is not None and "median n/a" in captured.out
