"""GigaDepth's training recipe as [data] / [train] / [model] options, each off by default: full frames,
its uniform noise, its edge mask and edge weight ramp, the L1 weight's ramp, crops drawn around near
pixels, and its finer output (one line per row, 1920 leaves, full resolution)."""

from dataclasses import replace

import numpy as np
import pytest
import torch
from scipy.optimize import minimize

from dotsim.frame_source import open_source
from tests.trainer_fixtures import tiny_config
from trainer.config import config_from_dict, load_config, resolution_mismatch
from trainer.model import build_model
from trainer.samples import (
    FrameDataset,
    frame_targets,
    resample_columns,
    resample_targets,
    stretched_columns,
    tilted_plane,
)
from trainer.train import batch_loss, loss_weights, train

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def with_data(cfg, **data):
    return replace(cfg, data=replace(cfg.data, **data))


def with_train(cfg, **keys):
    return replace(cfg, train=replace(cfg.train, **keys))


@pytest.fixture(scope="module")
def source(data):
    return open_source(data, "train")


def test_crop_sizes_0_give_batches_of_full_frames(source):
    cfg = with_data(tiny_config(1), crop_width=0, crop_height=0, noise_std=0.0, vertical_jitter=0)
    ds = FrameDataset(source.frames, source.rig, cfg.data, seed=0, augment=True)
    h, w = source.rig.camera.height, source.rig.camera.width
    for i in range(len(source.frames)):
        sample, frame = ds[i], source.frames[i].read(("ir",))
        assert int(sample["row0"]) == 0 and int(sample["x0"]) == 0
        assert sample["ir"].shape == (1, h, w) and sample["column"].shape == (-(-h // 2), -(-w // 2))
        gain = float(sample["ir"].sum()) / float(frame["ir"].astype(np.float32).sum())  # intensity_scale
        np.testing.assert_allclose(sample["ir"][0].numpy(), frame["ir"].astype(np.float32) * gain, rtol=1e-5)


def test_uniform_noise_has_a_random_amplitude_up_to_its_maximum(source):
    """Each sample adds U(0, a) per pixel, a = U(0, 1) x uniform_noise: the added noise is non-negative,
    below a, uniform (its mean a / 2), and a varies from sample to sample over (0, max)."""
    cfg = with_data(tiny_config(1), intensity_scale=(1.0, 1.0), noise_std=0.0, uniform_noise=0.3)
    ds = FrameDataset(source.frames[:1], source.rig, cfg.data, seed=0, augment=True)
    clean = FrameDataset(source.frames[:1], source.rig, with_data(cfg, uniform_noise=0.0).data, seed=0,
                         augment=True)
    amplitudes = []
    for epoch in range(24):
        ds.epoch = clean.epoch = epoch  # the same crop, another draw
        added = (ds[0]["ir"] - clean[0]["ir"]).numpy().ravel()
        top = added.max()
        assert added.min() >= -1e-6 and top < 0.3
        assert abs(added.mean() / top - 0.5) < 0.05  # uniform over [0, a)
        amplitudes.append(top)
    assert min(amplitudes) < 0.1 and max(amplitudes) > 0.2


def test_gigadepth_edge_mask_replaces_the_stored_one(source):
    """edge_threshold 10, edge_radius r: pixels within r (an ellipse, here a disc) of a disparity step of
    more than 2.5 px; a smaller step is no edge. Counted against the distance to the step's columns."""
    h, w = 40, 60
    disparity = np.full((h, w), 5.0)
    disparity[:, 30:] = 9.0  # a 4 px step between columns 29 and 30: Sobel 16
    disparity[:20, :10] = 6.0  # a 1 px step: Sobel 4, no edge
    frame = {"ir": np.zeros((h, w)), "visibility": np.ones((h, w)), "edge": np.ones((h, w)),
             "projector_column": np.full((h, w), 10.0), "disparity": disparity}
    cfg = with_data(tiny_config(1), edge_threshold=10.0, edge_radius=4).data
    edge = frame_targets(frame, source.rig, cfg)["edge"]
    columns = np.arange(w)
    distance = np.minimum(abs(columns - 29), abs(columns - 30))
    np.testing.assert_array_equal(edge, np.broadcast_to(distance <= 4, (h, w)).astype(np.float32))
    assert frame_targets(frame, source.rig, tiny_config(1).data)["edge"].all()  # default: the stored mask


def test_near_crops_hold_the_pixels_nearer_than_near_depth(source):
    """near_share 1: every crop is centred on (within a row of) a valid pixel nearer than near_depth, or
    moved inside the frame; near_share 0 crops miss the near pixels often. Depth from the disparity
    here as z = fx b / d, independently of the trainer."""
    rig = source.rig
    cfg = with_data(tiny_config(1), crop_width=16, crop_height=12)
    frames = [ref.read(("disparity", "visibility")) for ref in source.frames]
    depths = [rig.camera.fx * rig.baseline / np.where(f["disparity"] > 0, f["disparity"], np.nan)
              for f in frames]
    lit = [f["visibility"] > 0 for f in frames]
    near_depth = float(np.nanpercentile(np.concatenate([d.ravel() for d in depths]), 10))
    counts = {}
    for share in (0.0, 1.0):
        ds = FrameDataset(source.frames, rig, with_data(cfg, near_share=share, near_depth=near_depth).data,
                          seed=0, augment=True)
        holding = 0
        for epoch in range(6):
            ds.epoch = epoch
            for i, depth in enumerate(depths):
                s = ds[i]
                y0, x0 = 2 * int(s["row0"]), int(s["x0"])
                crop = (slice(y0, y0 + 12), slice(x0, x0 + 16))
                near = (depth[crop] < near_depth) & lit[i][crop]
                holding += bool(near.any())
                if share == 1.0 and ((depth < near_depth) & lit[i]).any():
                    assert near.any(), (i, epoch)
        counts[share] = holding
    assert counts[0.0] < counts[1.0]


@pytest.mark.parametrize("scale, shear", [(0.8, 0.0), (0.9, 0.2), (1.25, -0.15)])
def test_a_stretched_crop_shows_each_column_with_its_own_target(scale, shear):
    """A frame whose IR is its column index and whose projector column is a smooth ramp of it: the
    stretched crop's IR steps 1 / scale columns a pixel about the crop's centre, each row `shear` columns
    from the one above, and every output's target is the ramp at the column its IR shows (read off the
    IR, not from the stretch)."""
    h, w, width = 8, 200, 1088.0
    u = np.broadcast_to(np.arange(w, dtype=np.float32), (h, w))
    ramp = (2.5 * u + 7.0) / width
    first, columns = stretched_columns(60, 96, w, scale)
    assert first == 60  # the centre (107.5) is far enough inside to stay put
    columns = columns + shear * (np.arange(h) - (h - 1) / 2)[:, None]
    ir = resample_columns(u, columns)
    np.testing.assert_allclose(np.diff(ir, axis=1), 1 / scale, rtol=1e-4)
    np.testing.assert_allclose(np.diff(ir, axis=0), shear, atol=1e-4)
    np.testing.assert_allclose(ir[:, 47:49].mean(), 107.5, atol=1e-4)
    targets = resample_targets({"column": ramp[::2], "valid": np.ones((h // 2, w), bool),
                                "edge": np.zeros((h // 2, w), np.float32)}, columns[::2, ::2])
    assert targets["valid"].all()
    np.testing.assert_allclose(targets["column"], (2.5 * ir[::2, ::2] + 7.0) / width, rtol=1e-5)


def test_a_stretched_crop_never_blends_a_foreground_into_its_background():
    """Across a depth step (marked by the edge mask) a target takes a real pixel's column, the nearer
    one, never one between the two surfaces; off the mask it is interpolated."""
    h, w = 4, 200
    u = np.broadcast_to(np.arange(w, dtype=np.float32), (h, w))
    column = np.where(u < 100, u / 1000, u / 1000 + 0.2).astype(np.float32)
    edge = (np.abs(u - 99.5) < 3).astype(np.float32)
    for scale in (0.83, 0.97, 1.11, 1.2):
        _, columns = stretched_columns(52, 96, w, scale)
        t = resample_targets({"column": column, "valid": np.ones((h, w), bool), "edge": edge}, columns)
        near_step = np.abs(columns - 99.5) < 3
        assert np.isin(t["column"][:, near_step], column[0]).all()
        nearest = np.rint(columns[near_step]).astype(int)
        np.testing.assert_array_equal(t["column"][0, near_step], column[0, nearest])
        off = ~near_step & (np.abs(columns - 99.5) > 4)
        expected = np.where(columns < 100, columns / 1000, columns / 1000 + 0.2)
        np.testing.assert_allclose(t["column"][0, off], expected[off], rtol=1e-5)


def test_a_stretch_stays_inside_the_frame_or_leaves_what_is_outside_invalid():
    """Crops at the frame's sides move inward to fit; a full-width crop squeezed (scale < 1) cannot fit,
    and its columns beyond the frame are black and not trained on."""
    w = 200
    for x0 in (0, 104):
        _, columns = stretched_columns(x0, 96, w, 0.8)
        assert columns.min() >= 0 and columns.max() <= w - 1
    first, columns = stretched_columns(0, w, w, 0.8)
    outside = (columns < 0) | (columns > w - 1)
    assert first == 0 and outside.sum() == 40  # |k - 99.5| / 0.8 > 99.5: 20 columns a side
    frame = np.ones((2, w), np.float32)
    np.testing.assert_array_equal(resample_columns(frame, columns)[0] == 0, outside)
    t = resample_targets({"column": frame, "valid": np.ones((2, w), bool), "edge": 0 * frame}, columns)
    np.testing.assert_array_equal(t["valid"][0], ~outside)


def test_tilted_plane_is_the_pattern_on_a_tilted_plane():
    """Planes through the point at depth z0 on the optical axis, tilted by a degrees, intersected with
    each pixel's ray (f 435 px, baseline 2.5 cm): the pattern the camera sees along a row is the projector
    column u - d(u), so its stretch at the centre is 1 / (dx/du); down a column each row's pattern shifts by
    the change of d from row to row. tilted_plane gives both from the centre's disparity alone."""
    f, b = 435.0, 0.025
    u = np.arange(-40.0, 41.0)
    for z0, a in ((0.5, 60.0), (0.8, -35.0), (4.0, 75.0)):
        # the plane Z = z0 - X tan(a), the ray (X, Z) = Z (u / f, 1)
        depth = z0 / (1 + np.tan(np.radians(a)) * u / f)
        disparity = f * b / depth
        stretch = 1 / np.gradient(u - disparity)[40]
        shift = np.gradient(disparity)[40]  # the same plane turned about the horizontal axis, by rows
        got = tilted_plane(f * b / z0, f, a, a)
        np.testing.assert_allclose(got, (stretch, shift), rtol=1e-9)


def _tilt_misfit(gk, rows, x0, crop):
    """How far a crop is from rows read stretched by 1 / (1 - g) and shifted k px per row (gk = (g, k))."""
    h, w = crop.shape
    columns = stretched_columns(x0, w, rows.shape[1], 1 / (1 - gk[0]))[1]
    shifted = columns + gk[1] * (np.arange(h) - (h - 1) / 2)[:, None]
    return float(((resample_columns(rows, shifted) - crop) ** 2).sum())


def test_slant_stretches_and_shears_near_crops_within_what_their_depth_allows(source):
    """[data] slant 80 on rendered frames: each crop's rows are read stretched by s and shifted by k px per
    row (fitted to the frame's IR), with |1 - 1 / s| and |k| within d tan(80 deg) / f for the crop's median
    GT disparity d (from the frame's depth: f b / z), and varying from sample to sample."""
    cfg = with_data(tiny_config(1), crop_width=32, crop_height=16, noise_std=0.0, intensity_scale=(1.0, 1.0),
                    slant=80.0)
    plain = FrameDataset(source.frames, source.rig, with_data(cfg, slant=0.0).data, seed=0, augment=True)
    ds = FrameDataset(source.frames, source.rig, cfg.data, seed=0, augment=True)
    f, b = source.rig.camera.fx, source.rig.baseline
    fitted = []
    for i in range(len(source.frames)):
        frame = source.frames[i].read(("ir", "depth", "visibility"))
        ir = frame["ir"].astype(np.float32)
        for epoch in range(3):
            ds.epoch = plain.epoch = epoch
            s, p = ds[i], plain[i]
            assert int(s["row0"]) == int(p["row0"])
            rows = slice(2 * int(s["row0"]), 2 * int(s["row0"]) + 16)
            depth = frame["depth"][rows, int(p["x0"]) : int(p["x0"]) + 32]
            d = f * b / np.median(depth[(frame["visibility"][rows, int(p["x0"]) : int(p["x0"]) + 32] > 0)
                                         & np.isfinite(depth) & (depth > 0)])
            bound = d * np.tan(np.radians(80.0)) / f
            fit = (ir[rows], int(p["x0"]), s["ir"][0].numpy())
            grid = np.linspace(-1.1 * bound, 1.1 * bound, 23)
            start = min(((g, k) for g in grid for k in grid), key=lambda gk: _tilt_misfit(gk, *fit))
            step = grid[1] - grid[0]
            for _ in range(3):  # restarted: the misfit is smooth only piecewise
                simplex = np.array(start) + [[0, 0], [step, 0], [0, step]]
                best = minimize(_tilt_misfit, start, fit, method="Nelder-Mead",
                                options={"xatol": 1e-9, "fatol": 1e-14, "initial_simplex": simplex})
                start, step = best.x, step / 10
            assert best.fun < 1e-6 * (s["ir"][0].numpy() ** 2).sum()  # the crop is such a resampling
            assert abs(best.x[0]) <= bound * 1.01 and abs(best.x[1]) <= bound * 1.01
            fitted.append(best.x / bound)
    fitted = np.array(fitted)  # tan(a) / tan(80 deg) of the drawn tilts: a uniform in [-80, 80] deg
    assert (fitted.min(axis=0) < -0.2).all() and (fitted.max(axis=0) > 0.2).all()  # both ways, far


def test_slant_depth_leaves_crops_farther_than_it_as_they_are(source):
    """slant_depth: a crop whose median GT depth (f b / d) is nearer than it is tilted, a farther one read
    as without slant."""
    cfg = with_data(tiny_config(1), crop_width=32, crop_height=16, noise_std=0.0, intensity_scale=(1.0, 1.0),
                    slant=80.0)
    f, b = source.rig.camera.fx, source.rig.baseline
    depths = []
    for i, ref in enumerate(source.frames):
        frame = ref.read(("disparity", "visibility"))
        plain = FrameDataset(source.frames, source.rig, with_data(cfg, slant=0.0).data, seed=0, augment=True)
        p = plain[i]
        rows = slice(2 * int(p["row0"]), 2 * int(p["row0"]) + 16)
        cols = slice(int(p["x0"]), int(p["x0"]) + 32)
        d, lit = frame["disparity"][rows, cols], frame["visibility"][rows, cols] > 0
        depth = f * b / np.median(d[lit & (d > 0)])
        depths.append(depth)
        for limit, tilted in ((depth * 0.99, False), (depth * 1.01, True)):
            s = FrameDataset(source.frames, source.rig, with_data(cfg, slant_depth=limit).data, seed=0,
                             augment=True)[i]
            assert (not torch.equal(s["ir"], p["ir"])) == tilted, (i, limit)
    assert np.ptp(depths) > 0.1  # crops at several depths


def test_loss_weights_ramp_as_configured():
    """l1_weight -> l1_weight_end linearly over the run's steps; edge_weights piecewise in equal shares;
    both left out: the constants (the default, so today's configs train as before)."""
    cfg = with_train(tiny_config(1), l1_weight=1.0, l1_weight_end=4.0,
                     edge_weights=(0.0, 1.0, 2.0, 2.0, 5.0))
    got = [loss_weights(cfg, step, 100) for step in (0, 19, 20, 50, 80, 100)]
    assert [e for _, e in got] == [0.0, 0.0, 1.0, 2.0, 5.0, 5.0]
    np.testing.assert_allclose([w for w, _ in got], [1.0, 1.57, 1.6, 2.5, 3.4, 4.0])
    plain = tiny_config(1)
    assert loss_weights(plain, 37, 100) == (plain.train.l1_weight, plain.train.edge_weight)


def test_batch_loss_takes_the_step_weights(source):
    """batch_loss with weights (w1, we) equals the loss of a config whose constants are w1 and we."""
    cfg = tiny_config(1)
    ds = FrameDataset(source.frames[:2], source.rig, cfg.data, seed=0, augment=False)
    batch = {k: torch.stack([ds[i][k] for i in range(2)]) for k in ds[0]}
    torch.manual_seed(0)
    model = build_model(cfg, source.rig)
    with torch.no_grad():
        ramped, _ = batch_loss(model, batch, cfg, weights=(3.0, 0.5))
        constant, _ = batch_loss(model, batch, with_train(cfg, l1_weight=3.0, edge_weight=0.5))
        default, _ = batch_loss(model, batch, cfg)
    assert float(ramped) == float(constant) != float(default)


def test_training_runs_with_the_whole_recipe(source, tmp_path):
    """Every option at once, on full frames: finite losses, and a resumed run continues them exactly."""
    d = tiny_config(4).to_dict()
    d["data"].update(crop_width=0, crop_height=0, uniform_noise=0.3, edge_threshold=10.0, edge_radius=3,
                     near_share=0.5, near_depth=2.0)
    d["train"].update(l1_weight_end=4.0, edge_weights=[0.0, 1.0, 2.0, 2.0, 5.0], batch_size=2)
    cfg = config_from_dict(d, "recipe")
    whole = train(cfg, source, tmp_path / "whole", progress=False)["losses"]
    assert len(whole) == 4 and all(np.isfinite(whole))
    # stopped for time after its first step (with a checkpoint), then resumed: the same 4-step schedule
    first = train(cfg, source, tmp_path / "parts", progress=False, max_seconds=1e-9)["losses"]
    assert len(first) == 1
    rest = train(cfg, source, tmp_path / "parts", resume=True, progress=False)["losses"]
    np.testing.assert_allclose(first + rest, whole, rtol=1e-6)


def test_finer_output_is_settable_one_line_per_row_and_1920_leaves():
    """GigaDepth's Table 2 output: a full-resolution backbone ([model] stride 1), one weight set per row of
    the 512 px tall camera (lines 512) and 1920 leaves (classes [16, 12, 10]): valid, fitting the camera,
    and built with one classifier table per (line, parent) (counted on the meta device)."""
    d = load_config("train_table2").to_dict()
    d["model"].update(stride=1, lines=512, classes=[16, 12, 10], overlaps=[0, 3, 4])
    cfg = config_from_dict(d, "finer")
    assert resolution_mismatch(cfg, 432, 512) is None
    assert "lines = 512" in resolution_mismatch(replace(cfg, model=replace(cfg.model, stride=2)), 432, 512)
    rig = _table2_rig()
    with torch.device("meta"):
        model = build_model(replace(cfg, model=replace(cfg.model, min_depth=0.0)), rig)
    assert model.leaves == 1920 and model.rows == 512
    assert model.classifiers[2].layers[-1].weight.shape[0] == 512 * 16 * 12  # (line, parent) tables
    assert model.regressor.layers[-1].weight.shape[0] == 512 * 1920  # one output per (line, leaf)


def _table2_rig():
    from dotsim.rig.presets import get_preset

    return get_preset("ctd_synthetic")


def test_docstring_examples_of_the_schedules():
    import doctest

    from trainer import train as train_module

    result = doctest.testmod(train_module)
    assert result.attempted >= 1 and result.failed == 0
