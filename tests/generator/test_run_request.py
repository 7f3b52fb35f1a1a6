"""RunRequest (generator/run_request.py): a run's values checked once, with one-line errors naming
the option; the rig file read once per run and the pattern made once, however many scenes are
sampled; the engine chosen by one option (generator/run_request.py's Executor). Nothing here renders."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

import dotsim.rig.options
import generator.run_request
from commands.cli import build_parser
from generator.cli import executor_from_args
from generator.config import ConfigError, load_config
from generator.engines.local_pool import LocalExecutor
from generator.engines.ray_cluster import RayExecutor
from generator.engines.slurm import SlurmExecutor
from generator.engines.steps import prepare_run
from generator.render_worker import _sample
from generator.run_request import RunRequest

TINY = Path(__file__).resolve().parents[2] / "dotsim" / "configs" / "tiny.toml"


@pytest.mark.parametrize("changes, message", [
    ({"scenes": 0}, "--scenes 0: allowed: an integer >= 1"),
    ({"start": -1}, "--start -1: allowed: an integer >= 0"),
    ({"seed": True}, "--seed True: allowed: an integer >= 0"),
    ({"split": "val"}, "--split 'val': allowed: train or test"),
    ({"blender": "/no/blender"}, "--blender /no/blender: not an executable file"),
])
def test_bad_values_are_one_line_naming_the_option(tmp_path, changes, message):
    values = dict(config=load_config(TINY), out=tmp_path / "d", split="train", scenes=1) | changes
    with pytest.raises(ConfigError) as info:
        RunRequest(**values)
    assert str(info.value).startswith(message) and "\n" not in str(info.value)
    assert not (tmp_path / "d").exists()


def test_out_is_made_absolute_once(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    request = RunRequest(load_config(TINY), "rel/d", "test", 3, start=2)
    assert request.out == tmp_path / "rel" / "d" and request.indices == range(2, 5)
    assert not (tmp_path / "rel").exists()  # checked, not created


def test_rig_file_read_and_pattern_made_once_for_a_whole_run(tmp_path, monkeypatch):
    """load_config resolves the rig (Config.calibrated_rig); preparing the run and sampling scenes
    (in this process, as a worker does with the pickled job) neither reads it again nor remakes
    the pattern."""
    rig_reads, patterns = [], []
    configured_rig, make_pattern = dotsim.rig.options.configured_rig, generator.run_request.make_pattern
    monkeypatch.setattr(dotsim.rig.options, "configured_rig",
                        lambda *args: rig_reads.append(args) or configured_rig(*args))
    monkeypatch.setattr(generator.run_request, "make_pattern",
                        lambda *args: patterns.append(args) or make_pattern(*args))
    request = RunRequest(load_config(TINY), tmp_path / "d", "train", 3)
    job = prepare_run(request)
    specs = [_sample(job, index) for index in request.indices]
    assert (len(rig_reads), len(patterns)) == (1, 1)
    assert all(spec.rig == request.rig.rig for spec in specs)
    assert request.pattern.sha256 == specs[0].pattern.sha256


def parsed(*options: str):
    return build_parser().parse_args(["generate", "--config", str(TINY), "--out", os.devnull,
                                      "--split", "train", "--scenes", "1", *options])


def test_one_option_chooses_the_engine():
    local = executor_from_args(parsed("--workers", "3"))
    assert isinstance(local, LocalExecutor) and local.workers == 3
    ray = executor_from_args(parsed("--ray", "local", "--workers", "2"))
    assert isinstance(ray, RayExecutor) and (ray.address, ray.local_workers) == ("local", 2)
    assert isinstance(executor_from_args(parsed("--slurm-dry-run")), SlurmExecutor)
    with pytest.raises(ConfigError, match=r"^--ray and --slurm: choose one$"):
        executor_from_args(parsed("--ray", "auto", "--slurm"))
