"""bench.trainer_screen run as the docs say (`python -m bench.trainer_screen`, its own process): two
variants of train_tiny on oracle frames, 3 steps each, scored on held-out frames, their FLOPs
counted, the table reported; and its settings' examples (doctest)."""

import json
import os
import subprocess
import sys

from dotsim.oracle_dataset import make_dataset

# One intra-op thread: on the shared 2-core machine two threads measured 3-10x slower per step.
ENV = {**os.environ, "OMP_NUM_THREADS": "1"}


def screen(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bench.trainer_screen", *args], capture_output=True,
                          text=True, env=ENV)


def test_settings_are_toml_values_of_dotted_keys():
    done = subprocess.run([sys.executable, "-m", "doctest", "-v", "bench/trainer_screen.py"],
                          capture_output=True, text=True, env=ENV)
    assert done.returncode == 0 and "with_settings" in done.stdout, done.stdout[-2000:] + done.stderr


def test_two_variants_train_the_same_steps_and_are_reported(tmp_path):
    data = make_dataset(tmp_path / "ds", scenes=2, frames_per_scene=2)
    val = make_dataset(tmp_path / "val", scenes=1, frames_per_scene=2, seed=4)
    common = ["--config", "train_tiny", "--data", str(data), "--val-data", str(val), "--steps", "3",
              "--val-frames", "2", "--out", str(tmp_path / "screens")]
    full = ["--name", "full", "--set", "model.stride=1", "--set", "model.lines=90"]
    for variant in (["--name", "base"], full):
        done = screen(*common, *variant)
        assert done.returncode == 0, done.stderr[-2000:]
    lines = [json.loads(line) for line in (tmp_path / "screens" / "results.jsonl").read_text().splitlines()]
    assert [r["name"] for r in lines] == ["base", "full"] and {r["steps"] for r in lines} == {3}
    assert 3.5 < lines[1]["gflop_per_step"] / lines[0]["gflop_per_step"] < 4.5  # full resolution: 4x
    assert {"all o(0.5)", "solvable o(5)"} <= set(lines[0]["validation"])
    by_class = lines[0]["by_class"]
    assert {"all", "0-1", "edge", "off edge"} <= set(by_class)
    # the classes split the same valid pixels validation scores: ranges and edges each add up to all
    ranges = [k for k in by_class if "-" in k]
    assert sum(by_class[k]["pixels"] for k in ranges) == by_class["all"]["pixels"]
    assert by_class["edge"]["pixels"] + by_class["off edge"]["pixels"] == by_class["all"]["pixels"]
    all_rate = by_class["all"]["o(0.5)"] * by_class["all"]["pixels"]
    counted = sum(by_class[k]["o(0.5)"] * by_class[k]["pixels"] for k in ranges if by_class[k]["pixels"])
    assert abs(counted - all_rate) < 1e-6
    assert abs(by_class["all"]["o(0.5)"] - lines[0]["validation"]["all o(0.5)"]) < 1e-12
    done = screen("--report", str(tmp_path / "screens"))
    assert done.returncode == 0, done.stderr[-2000:]
    report = done.stdout
    assert "| base | as the config | 3 |" in report and "model.stride=1, model.lines=90" in report
    assert "by GT depth range (m) and pixel class" in report and "| off edge |" in report


def test_time_steps_the_variant_and_the_config_in_turns(tmp_path):
    data = make_dataset(tmp_path / "ds", scenes=2, frames_per_scene=2)
    common = ["--config", "train_tiny", "--data", str(data), "--out", str(tmp_path / "screens")]
    done = screen(*common, "--time", "2", "--rounds", "3", "--name", "full", "--set", "model.stride=1")
    assert done.returncode == 0, done.stderr[-2000:]
    (line,) = [json.loads(t) for t in (tmp_path / "screens" / "timings.jsonl").read_text().splitlines()]
    seconds = line["seconds_per_step"]
    assert set(seconds) == {"config", "full"} and all(len(v) == 3 and min(v) > 0 for v in seconds.values())
    ratios = sorted(v / c for v, c in zip(seconds["full"], seconds["config"], strict=True))
    assert line["ratio"] == {"median": ratios[1], "min": ratios[0], "max": ratios[2]}
    assert line["median_seconds"]["config"] == sorted(seconds["config"])[1]
    assert not (tmp_path / "screens" / "results.jsonl").exists()  # nothing trained
    report = screen("--report", str(tmp_path / "screens"))
    assert report.returncode == 0, report.stderr[-2000:]
    assert "| full | model.stride=1 | 3 x 2 |" in report.stdout
    refused = screen(*common, "--time", "2", "--name", "config")
    assert refused.returncode == 2 and "other than 'config'" in refused.stderr
