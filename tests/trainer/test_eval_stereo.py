"""`dotsim eval` on a stereo pair's data: SGBM between the left and right IR as a row of its own, scored
as the depth it gives (trainer/evaluate.py), recounted here from the planes' true depth."""

from __future__ import annotations

import dataclasses

import numpy as np

from dotsim.frame_source import open_source
from dotsim.oracle_dataset import make_dataset
from dotsim.shards.writer import export_webdataset
from tests.trainer_fixtures import tiny_config
from trainer.evaluate import evaluate, row_of, sgbm_nearest_depth
from trainer.sgbm import num_disparities_for, stereo_sgbm_disparity
from trainer.train import train


def test_eval_scores_the_pairs_sgbm_in_projector_disparity(tmp_path):
    data = make_dataset(tmp_path / "data", 2, test_scenes=2, pair=True)  # D415 at 128 x 72, 36 rows
    cfg = tiny_config(2)
    cfg = dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, lines=36))
    train(cfg, open_source(data, "train"), tmp_path / "run", progress=False)
    rows = evaluate(tmp_path / "run" / "checkpoint.pt", open_source(data, "test"), tmp_path / "eval",
                    images=0, progress=False)
    stereo = row_of(rows, "sgbm-stereo", "all")
    assert stereo is not None and row_of(rows, "sgbm-stereo", "solvable") is not None
    assert "sgbm-stereo: SGBM between the left and right IR" in (tmp_path / "eval" / "eval.md").read_text()
    # by hand: the pair's disparity d_s = fx B_s / z, scored against the projector's fx B_p / z of the
    # true depth: d_s B_p / B_s (the D415's projector sits half way: B_p / B_s = 0.5)
    source = open_source(data, "test")
    frames, rig = source.frames, source.rig
    b_pair, b_projector = rig.second_camera_translation[0], rig.projector_translation[0]
    n = num_disparities_for(rig, sgbm_nearest_depth(frames, rig), b_pair)
    over = total = 0
    for ref in frames:
        f = ref.read(("ir", "ir_right", "depth", "visibility"))
        pred = stereo_sgbm_disparity(f["ir"].astype(np.float32), f["ir_right"].astype(np.float32), n)
        truth = rig.camera.fx * b_projector / f["depth"].astype(np.float64)
        valid = f["visibility"] > 0
        over += int(np.sum(~(np.abs(pred * (b_projector / b_pair) - truth)[valid] <= 0.5)))
        total += int(valid.sum())
    assert stereo["pixels"] == total and abs(stereo["o(0.5)"] - over / total) < 1e-9
    assert stereo["o(0.5)"] < 0.2  # unconverted, d_s would be twice the truth: every pixel an outlier
    # shards exported without the right IR: no such row (their scene.json still lists ir_right)
    export_webdataset(data, tmp_path / "shards", split="test", channels=["ir", "visibility", "edge", "depth"])
    rows = evaluate(tmp_path / "run" / "checkpoint.pt", open_source(tmp_path / "shards", "test"),
                    tmp_path / "eval_shards",
                    images=0, progress=False)
    assert row_of(rows, "sgbm-stereo", "all") is None and row_of(rows, "network", "all")["pixels"] == total
