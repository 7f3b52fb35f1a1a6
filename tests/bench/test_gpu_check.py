"""bench.gpu_check's dry run on CPU at 122 x 90 (4 training frames, 2 steps), so the prepared GPU check
cannot rot between the sessions that have a GPU: every section runs and reports, on real exported
shards of oracle frames, with a real tiny network and a real eval against SGBM."""

import json
import os
import subprocess
import sys

from dotsim.frame_source import open_source
from dotsim.oracle_dataset import make_dataset
from dotsim.shards.writer import export_webdataset

TRAINING = ["ir", "projector_column", "visibility", "edge"]


# One intra-op thread: on the shared 2-core machine two threads measured 3-10x slower per step.
ENV = {**os.environ, "OMP_NUM_THREADS": "1"}


def gpu_check(*args: str) -> subprocess.CompletedProcess:
    """`python -m bench.gpu_check ARGS`, as the docs run it (its own process)."""
    return subprocess.run([sys.executable, "-m", "bench.gpu_check", *args], capture_output=True, text=True,
                          env=ENV)


def test_every_section_runs_and_reports_as_it_goes(tmp_path):
    data = make_dataset(tmp_path / "ds", scenes=2, frames_per_scene=2, test_scenes=1, ir_bits=10)
    for split in ("train", "test"):
        export_webdataset(data, tmp_path / split, split=split, precision="training", channels=TRAINING)
    out = tmp_path / "out"
    done = gpu_check("--device", "cpu", "--small", "--train", str(tmp_path / "train"), "--test",
                     str(tmp_path / "test"), "--out", str(out), "--minutes", "6", "--repeats", "1",
                     "--train-steps", "2", "--variants", "eager", "--max-steps", "2",
                     "--tests", "tests/trainer/test_trainer_cuda.py")
    assert done.returncode == 0, done.stderr[-2000:]
    results = json.loads((out / "gpu_check.json").read_text())
    assert results["environment"][0]["device"] == "cpu"
    timed = [r for r in results["inference"] if "ms" in r]
    assert {r["precision"] for r in timed} == {"float32", "float16", "bfloat16"}
    assert all(r["ms"] > 0 and r["variant"] == "eager" for r in timed)
    trained = [r for r in results["training"] if "ms_per_step" in r]
    assert {r["config"] for r in trained} == {"train_tiny (oracle)", "train_tiny (carried)"}
    assert all(r["finite"] for r in trained)
    run, scores = results["accuracy"]
    assert run["steps"] == 2 and run["train_frames"] == 4  # one batch
    assert scores["network"]["pixels"] == scores["sgbm"]["pixels"] > 0
    assert "o(0.5)" in (out / "eval.md").read_text()
    assert "skipped" in results["tests"][0]["summary"]  # the CUDA tests, on a machine without CUDA
    assert (out / "gpu_check.md").read_text().startswith("# GPU check on cpu")
    refused = gpu_check("--train", "x", "--test", "y", "--out", str(out), "--sections", "inference,nope")
    assert refused.returncode == 2 and "nope" in refused.stderr


def test_table2_section_trains_on_full_frames_and_writes_a_point_of_the_curve(tmp_path):
    data = make_dataset(tmp_path / "ds", scenes=2, frames_per_scene=2, test_scenes=1, ir_bits=10)
    for split in ("train", "test"):
        export_webdataset(data, tmp_path / split, split=split, precision="training", channels=TRAINING)
    out = tmp_path / "out"
    done = gpu_check("--device", "cpu", "--small", "--sections", "table2", "--table2-train",
                     str(tmp_path / "train"), "--table2-seen-test", str(tmp_path / "test"), "--table2-test",
                     str(tmp_path / "test"), "--out", str(out), "--minutes", "3", "--max-steps", "2",
                     "--test-frames", "2")
    assert done.returncode == 0, done.stderr[-2000:]
    point = json.loads((out / "table2_point.jsonl").read_text())
    rig = open_source(tmp_path / "train", "train").rig
    # two steps of 4 whole frames, counted from the rig, not from the code's own pixel count
    assert point["steps"] == 2 and point["frames"] == 4 and point["full_frames"]
    assert point["pixel_samples"] == 2 * 4 * rig.camera.width * rig.camera.height
    assert set(point["tests"]) == {"seen meshes", "disjoint meshes"}
    for rates in point["tests"].values():
        assert rates["pixels"] > 0 and 0 <= rates["o(5)"] <= rates["o(0.5)"] <= 1
    # the line joins bench.trainer_scaling's curve: its report reads it as one of its points
    (tmp_path / "curve").mkdir()
    (tmp_path / "curve" / "results.jsonl").write_text((out / "table2_point.jsonl").read_text())
    shown = subprocess.run([sys.executable, "-m", "bench.trainer_scaling", "--report", str(tmp_path / "curve")
                            ], capture_output=True, text=True, env=ENV)
    assert shown.returncode == 0 and "| 2 | 4 | cpu |" in shown.stdout, shown.stderr[-2000:]
    refused = gpu_check("--out", str(out), "--sections", "table2")
    assert refused.returncode == 2 and "--table2-train" in refused.stderr
    refused = gpu_check("--out", str(out), "--sections", "accuracy", "--train", "x")
    assert refused.returncode == 2 and "needs --test" in refused.stderr
