"""One scorer: `dotsim eval` and training's validation count with trainer.scoring.Scorer, so on the same
frames with the same network they give the same o(t), over the valid and over the solvable pixels."""

from __future__ import annotations

from dotsim.frame_source import open_source
from dotsim.oracle_dataset import make_dataset
from tests.trainer_fixtures import tiny_config
from trainer.evaluate import evaluate, row_of
from trainer.metrics import THRESHOLDS
from trainer.train import train


def test_eval_and_validation_give_the_same_counts_on_the_same_frames(tmp_path):
    data = make_dataset(tmp_path / "data", 2, test_scenes=2)
    test = open_source(data, "test")
    # validation on every test frame (val_frames 0: all) at the last step, whose network is the checkpoint's
    result = train(tiny_config(2), open_source(data, "train"), tmp_path / "run", progress=False,
                   validation=test, val_frames=0)
    rows = evaluate(tmp_path / "run" / "checkpoint.pt", test, tmp_path / "eval", images=0, progress=False)
    rates = result["validation"]
    assert {name.split(" o(")[0] for name in rates} == {"all", "solvable"}
    for name in ("all", "solvable"):
        row = row_of(rows, "network", name)
        assert row["pixels"] > 0
        for t in THRESHOLDS:
            assert rates[f"{name} o({t:g})"] == row[f"o({t:g})"]


def test_slanted_pixels_are_where_a_plane_tilts_off_the_edge_mask():
    """The disparity of planes z = 1 / (a + b u) (disparity linear in the column, fx b (a + b u)): the
    left half facing the camera, the right half tilted 0.08 px per px, a band of rows tilted down the
    columns; slanted where the analytic slope exceeds 0.05, never on the edge mask, not where GT is
    missing. And the module's doctests."""
    import doctest

    import numpy as np

    from trainer import scoring

    h, w = 40, 60
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    disparity = np.where(u < 30, 12.0, 12.0 + 0.08 * (u - 30))
    disparity[30:] = 8.0 + 0.06 * v[30:]
    disparity[:5, 40:] = np.nan
    edge = np.zeros((h, w))
    edge[:, 28:33] = 1  # the crease between the halves
    edge[28:33] = 1  # and the seam to the band
    valid = np.isfinite(disparity)
    depth = 1.0 / disparity
    classes = scoring.pixel_classes(valid, depth, edge, disparity=disparity)
    expected = (u > 30) & (v < 30) | (v >= 30)
    expected &= (edge == 0) & valid
    expected[5, 40:] = expected[:5, 39] = False  # beside the missing GT: no slope
    np.testing.assert_array_equal(classes["slanted"], expected)
    assert "slanted" not in scoring.pixel_classes(valid, depth, None, disparity=disparity)
    result = doctest.testmod(scoring)
    assert result.attempted >= 2 and result.failed == 0
