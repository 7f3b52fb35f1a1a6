"""bench.trainer_scaling run as its docstring says (its own process): train_tiny at four budgets (each
run to its last step, whole epochs or not) on oracle frames, scored on two test sets, a rerun skipping
the budgets done, the report's fits, a run trained elsewhere added by its checkpoint (and refused
when it is of another network or missing); and the fit against a power law computed by hand (its doctests)."""

import json
import os
import subprocess
import sys

from dotsim.oracle_dataset import make_dataset

# One intra-op thread: on the shared 2-core machine two threads measured 3-10x slower per step.
ENV = {**os.environ, "OMP_NUM_THREADS": "1"}
STEP = 4 * 96 * 64  # train_tiny: batch 4 of 96 x 64 crops


def scaling(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bench.trainer_scaling", *args], capture_output=True,
                          text=True, env=ENV)


def test_fit_recovers_a_power_law_and_names_the_budget_it_reaches_a_rate_at():
    done = subprocess.run([sys.executable, "-m", "doctest", "-v", "bench/trainer_scaling.py"],
                          capture_output=True, text=True, env=ENV)
    assert done.returncode == 0 and "power_law_fit" in done.stdout, done.stdout[-2000:] + done.stderr


def test_four_budgets_on_two_tests_a_rerun_skipping_them_and_a_run_trained_elsewhere(tmp_path):
    # 8 training frames, 2 steps an epoch: the 5-step budget takes 2.5 epochs, all of whose steps run
    data = make_dataset(tmp_path / "ds", scenes=2, frames_per_scene=4, test_scenes=1)
    seen = make_dataset(tmp_path / "seen", scenes=0, frames_per_scene=2, test_scenes=1, seed=5)
    common = ["--config", "train_tiny", "--data", str(data), "--test-data", str(data),
              "--seen-test-data", str(seen), "--test-frames", "2", "--out", str(tmp_path / "curve"),
              "--budgets", ",".join(str(n * STEP) for n in (1, 2, 3, 5))]
    done = scaling(*common)
    assert done.returncode == 0, done.stderr[-2000:]
    lines = [json.loads(line) for line in (tmp_path / "curve" / "results.jsonl").read_text().splitlines()]
    assert [r["steps"] for r in lines] == [1, 2, 3, 5]
    assert [r["pixel_samples"] for r in lines] == [n * STEP for n in (1, 2, 3, 5)]
    for r in lines:
        assert set(r["tests"]) == {"seen meshes", "disjoint meshes"}
        assert all(0 <= t["o(5)"] <= t["o(0.5)"] <= 1 and t["pixels"] > 0 for t in r["tests"].values())
    again = scaling(*common)
    assert again.returncode == 0 and again.stdout.count("skipped") == 4, again.stderr[-2000:]
    assert len((tmp_path / "curve" / "results.jsonl").read_text().splitlines()) == 4
    assert "| pixel-samples | steps | frames | where | seen meshes o(0.5)" in again.stdout
    assert again.stdout.count("over 4 points") + again.stdout.count("no fit") == 2

    # a run trained elsewhere joins as a point: its steps and crops read from its checkpoint, scored alike
    run = tmp_path / "curve" / "run_5" / "checkpoint.pt"
    other = [*common[:-4], "--out", str(tmp_path / "other")]
    added = scaling(*other, "--run", str(run))
    assert added.returncode == 0, added.stderr[-2000:]
    (point,) = [json.loads(line) for line in (tmp_path / "other" / "results.jsonl").read_text().splitlines()]
    assert (point["steps"], point["pixel_samples"], point["run"]) == (5, 5 * STEP, str(run))
    assert point["tests"] == lines[-1]["tests"]  # the same checkpoint on the same frames
    assert "skipped" in scaling(*other, "--run", str(run)).stdout
    # a run of another network, or no checkpoint at all: a clear error naming it, nothing added
    wrong = scaling(*[a if a != "train_tiny" else "train_cpu" for a in other], "--run", str(run))
    assert wrong.returncode == 2 and "[model]" in wrong.stderr and str(run) in wrong.stderr, wrong.stderr
    assert "Traceback" not in wrong.stderr
    missing = scaling(*other, "--run", str(tmp_path / "nothing.pt"))
    assert missing.returncode == 2 and "nothing.pt: checkpoint not found" in missing.stderr, missing.stderr
    assert len((tmp_path / "other" / "results.jsonl").read_text().splitlines()) == 1
