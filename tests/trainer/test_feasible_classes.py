"""The tree chooses among the classes a pixel's image column allows for the config's depth range
([model] min_depth to the rig's max_depth): the range checked against an independent projection of
sampled depths on rigs with and without rotation, and the true class never excluded on rendered frames."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from dotsim.frame_source import open_source
from dotsim.rig.geometry import Intrinsics, Rig, rotation_matrix
from dotsim.rig.presets import get_preset
from generator.config import config_from_dict, load_config
from generator.driver import generate
from tests.trainer_fixtures import tiny_config
from trainer.config import Config
from trainer.model import FEASIBLE_MARGIN, build_model
from trainer.samples import FrameDataset

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py

RECTIFIED = get_preset("structure_core").scaled(0.1)
ROTATED = Rig(name="rotated", camera=Intrinsics.centred(122, 90, 110.0),
              projector=Intrinsics(320, 300, 220.0, 221.0, 150.5, 160.0),
              projector_translation=(0.06, 0.012, -0.008),
              projector_rotation=rotation_matrix(np.radians(2.0), np.radians(-3.0), np.radians(1.5)),
              max_depth=8.0)


def restricted(min_depth: float) -> Config:
    cfg = tiny_config(10)
    return replace(cfg, model=replace(cfg.model, min_depth=min_depth))


def sampled_range(rig: Rig, u: float, v: float, near: float, far: float) -> tuple[float, float]:
    """The smallest and largest normalised projector column of 4000 depths between near and far on the
    ray of pixel (u, v), projected by hand: X = z K^-1 (u, v, 1), X_p = R (X - t), x = fx X_p / Z_p + cx."""
    cam, proj = rig.camera, rig.projector
    z = np.geomspace(near, far, 4000)
    points = z[:, None] * np.array([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0])
    in_projector = (points - np.array(rig.projector_translation)) @ np.array(rig.projector_rotation).T
    x = proj.fx * in_projector[:, 0] / in_projector[:, 2] + proj.cx
    return float(x.min() / proj.width), float(x.max() / proj.width)


@pytest.mark.parametrize("rig", [RECTIFIED, ROTATED], ids=["rectified", "rotated"])
def test_feasible_range_equals_an_independent_projection_of_sampled_depths(rig):
    cfg = restricted(0.3)
    model = build_model(cfg, rig)
    leaves, p = model.leaves, cfg.model.column_padding
    assert model.feasible.shape == ((rig.camera.height + 1) // 2, rig.camera.width, 2)
    rng = np.random.default_rng(0)
    for row, u in zip(rng.integers(0, model.feasible.shape[0], 40), rng.integers(0, rig.camera.width, 40),
                      strict=True):
        low, high = sampled_range(rig, u, 2.0 * row, 0.3, rig.max_depth)
        got = model.feasible[row, u].double().numpy() / leaves
        np.testing.assert_allclose((got - p) / (1 - 2 * p), [low, high], atol=2e-6)
    assert build_model(tiny_config(10), rig).feasible is None  # min_depth 0: every class


def test_children_are_feasible_exactly_where_their_leaves_meet_the_range():
    """Per level, a class may be chosen iff some leaf of it lies within FEASIBLE_MARGIN of the pixel's
    range, found here by walking the leaves one by one; a pixel with no feasible child keeps all."""
    model = build_model(restricted(0.5), RECTIFIED)
    cfg = model.cfg
    ranges = torch.tensor([[10.3, 25.9], [0.0, 3.2], [120.4, 127.0], [300.0, 400.0]])
    for level, (c, o) in enumerate(zip(cfg.classes, cfg.overlaps, strict=True)):
        per_class = model.leaves // math.prod(cfg.classes[: level + 1])
        classes = math.prod(cfg.classes[: level + 1])
        for parent in range(math.prod(cfg.classes[:level])):
            first = torch.full((len(ranges),), parent * c)
            got = model._feasible_children(level, first, ranges)
            for n, (low, high) in enumerate(ranges.tolist()):
                want = []
                for k in range(c + 2 * o):
                    g = parent * c + k - o
                    leaves = range(g * per_class, (g + 1) * per_class) if 0 <= g < classes else []
                    want.append(any(leaf + 1 > low - FEASIBLE_MARGIN and leaf <= high + FEASIBLE_MARGIN
                                    for leaf in leaves))
                if not any(want):
                    want = [True] * (c + 2 * o)
                assert got[n].tolist() == want, (level, parent, n)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """One tiny Cycles scene (4 frames) with the built-in tiny config's rectified rig, one with a
    rotated and shifted projector."""
    out = tmp_path_factory.mktemp("rendered")
    tiny = load_config("tiny")
    rotated = config_from_dict({**{k: v for k, v in tiny.to_dict().items() if k != "source"},
                                "rig": {**tiny.to_dict()["rig"], "projector_rotation_y": -3.0,
                                        "projector_rotation_x": 2.0, "projector_y": 0.01}}, "rotated")
    for name, config in (("rectified", tiny), ("rotated", rotated)):
        generate(config, out / name, "train", 1, seed=5, progress=False)
    return out


@pytest.mark.parametrize("name", ["rectified", "rotated"])
def test_the_true_class_is_never_excluded_on_rendered_frames(rendered, name):
    """Every valid pixel no nearer than min_depth keeps its true class at every level, whole frames and
    random crops alike: in_range holds and the cross-entropy over the feasible children is finite."""
    source = open_source(rendered / name, "train")
    frames, rig = source.frames, source.rig
    assert rig.is_rectified == (name == "rectified")
    near = 0.4 * 0.875  # the tiny config's nearest object centre, less a quarter of its largest size
    cfg = restricted(near)
    model = build_model(cfg, rig)
    whole = replace(cfg.data, crop_width=0, crop_height=0)
    for data in (FrameDataset(frames, rig, whole, 0, augment=False),
                 FrameDataset(frames, rig, cfg.data, 0, augment=True)):  # 64 x 48 crops
        for k in range(len(data)):
            sample = {key: value[None] for key, value in data[k].items()}
            depth = frames[k].read(("depth",))["depth"]
            rows = slice(2 * int(sample["row0"]), None, 2)
            cols = slice(int(sample["x0"]), None, 2)
            h, w = sample["valid"].shape[1:]
            far_enough = torch.from_numpy(depth[rows, cols][:h, :w] >= near)
            valid = sample["valid"] & far_enough
            assert valid.sum() > 100
            assert model.in_range(sample["row0"], sample["x0"], sample["column"])[valid].all()
            with torch.no_grad():
                feat = model.features(sample["ir"])
                terms = model.loss_terms(feat, sample["row0"], sample["column"], valid, sample["x0"])
            assert all(torch.isfinite(ce).all() for ce in terms["ce"])
    # and a range that does exclude: depths from 3 m on leave the pixels nearer than 1.5 m out (2.5 m
    # would lie within FEASIBLE_MARGIN of 3 m at this size)
    far = build_model(restricted(3.0), rig)
    first = FrameDataset(frames, rig, whole, 0, augment=False)[0]
    sample = {key: value[None] for key, value in first.items()}
    depth = frames[0].read(("depth",))["depth"][0::2, 0::2]
    near_pixels = sample["valid"][0] & torch.from_numpy(depth < 1.5)
    assert near_pixels.any()
    assert not far.in_range(sample["row0"], sample["x0"], sample["column"])[0][near_pixels].any()


def test_a_restricted_network_trains_and_routes_only_to_feasible_leaves(data, tmp_path):
    """Trained with min_depth 0.5 m (the oracle scenes' nearest surfaces are 0.6 m away) the loss is
    finite; and with classifiers biased hard towards each parent's first child and the regressor's
    offset 0, every pixel still lands on a leaf of its range, where the same weights without the range
    send nearly all to the far left."""
    from trainer.train import train

    result = train(restricted(0.5), open_source(data, "train"), tmp_path / "run", progress=False)
    assert len(result["losses"]) == 10 and np.isfinite(result["losses"]).all()
    source = open_source(data, "test")
    frames, rig = source.frames, source.rig
    ir = torch.from_numpy(frames[0].read(("ir",))["ir"].astype(np.float32))[None, None]
    leaves, shape = {}, None
    for min_depth in (0.5, 0.0):
        torch.manual_seed(0)
        model = build_model(restricted(min_depth), rig).eval()
        with torch.no_grad():
            for classifier in model.classifiers:
                classifier.layers[-1].bias.zero_()
                classifier.layers[-1].bias[:, 0] = 100.0
            model.regressor.layers[-1].weight.zero_()
            model.regressor.layers[-1].bias.zero_()
            column = model(ir)[0]
        shape = column.shape
        leaves[min_depth] = (model.pad_column(column).reshape(-1) * model.leaves).round()
    low, high = build_model(restricted(0.5), rig).pixel_ranges(torch.zeros(1, dtype=torch.long), None,
                                                               *shape).unbind(1)
    for min_depth, leaf in leaves.items():
        share = float(((leaf + 1 > low - FEASIBLE_MARGIN) & (leaf <= high + FEASIBLE_MARGIN)).float().mean())
        assert share == 1.0 if min_depth else share < 0.05
