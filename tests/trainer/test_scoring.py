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
