"""bench.trainer_accuracy's dry run with two test sets: a disjoint-mesh and a seen-mesh one (new scenes of
the training meshes, as DepthInSpace tests), each evaluated and reported with its goals; run as the docs
run it (`python -m bench.trainer_accuracy`, its own process)."""

import os
import subprocess
import sys

from dotsim.oracle_dataset import make_dataset

# One intra-op thread: on the shared 2-core machine two threads measured 3-10x slower per step.
ENV = {**os.environ, "OMP_NUM_THREADS": "1"}


def test_both_test_sets_are_evaluated_and_reported(tmp_path):
    data = make_dataset(tmp_path / "ds", scenes=2, frames_per_scene=2, test_scenes=1, seed=7)
    seen = make_dataset(tmp_path / "seen", scenes=0, frames_per_scene=2, test_scenes=1, seed=8)
    out = tmp_path / "bench"
    done = subprocess.run([sys.executable, "-m", "bench.trainer_accuracy", "--data", str(data),
                           "--seen-test-data", str(seen), "--config", "train_tiny", "--minutes", "0.01",
                           "--out", str(out)], capture_output=True, text=True, env=ENV)
    assert done.returncode == 0, done.stderr[-2000:]
    text = done.stdout
    assert "test split, disjoint meshes:" in text and "test split, seen meshes:" in text
    assert text.count("network o(0.5)") == 2
    assert "test, seen meshes: 1 scenes (2 frames)" in text
    assert (out / "eval" / "eval.md").is_file() and (out / "eval_seen" / "eval.md").is_file()
