"""bench.trainer_screen's dry run: two variants of train_tiny on oracle frames, 3 steps each, scored on
held-out frames, their FLOPs counted, the table reported."""

import json

import pytest

from bench.trainer_screen import main, with_settings
from tests.trainer_fixtures import make_dataset


def test_settings_are_toml_values_of_dotted_keys():
    base = {"seed": 0, "model": {"lines": 45, "min_depth": 0.0}, "train": {"lr_schedule": "step"}}
    got = with_settings(base, ["model.min_depth=0.2", 'train.lr_schedule = "cosine"', "seed=3"])
    assert got == {"seed": 3, "model": {"lines": 45, "min_depth": 0.2}, "train": {"lr_schedule": "cosine"}}
    assert base["model"]["min_depth"] == 0.0  # a copy


@pytest.mark.usefixtures("one_thread")
def test_two_variants_train_the_same_steps_and_are_reported(tmp_path, capsys):
    data = make_dataset(tmp_path / "ds", scenes=2, frames_per_scene=2)
    val = make_dataset(tmp_path / "val", scenes=1, frames_per_scene=2, seed=4)
    common = ["--config", "train_tiny", "--data", str(data), "--val-data", str(val), "--steps", "3",
              "--val-frames", "2", "--out", str(tmp_path / "screens")]
    assert main([*common, "--name", "base"]) == 0
    assert main([*common, "--name", "full", "--set", "model.stride=1", "--set", "model.lines=90"]) == 0
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
    capsys.readouterr()
    assert main(["--report", str(tmp_path / "screens")]) == 0
    report = capsys.readouterr().out
    assert "| base | as the config | 3 |" in report and "model.stride=1, model.lines=90" in report
    assert "by GT depth range (m) and pixel class" in report and "| off edge |" in report
