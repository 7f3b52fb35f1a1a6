"""What makes a rerun of `dotsim generate` into a dataset a resume (generator/engines/steps.py): the same
config, split and seed as the dataset's generate.json, where a key a later dotsim added to the config
counts as the same when it keeps its default (it renders as before it existed)."""

from __future__ import annotations

import json

import pytest

from generator.config import Config, ConfigError, config_from_dict
from generator.engines.steps import RUN_FILE, _check_existing_run, _run_record


def written_before_the_new_keys(tmp_path, config: Config) -> None:
    """generate.json as a dotsim without [sensor] speckle_* and [rig] stereo would have written it."""
    record = _run_record(config, "train", 0)
    for section, key in (("sensor", "speckle_contrast"), ("sensor", "speckle_grain"), ("rig", "stereo")):
        record["config"][section].pop(key)
    (tmp_path / RUN_FILE).write_text(json.dumps(record))


def test_a_dataset_from_before_a_new_key_resumes_while_the_key_keeps_its_default(tmp_path):
    written_before_the_new_keys(tmp_path, Config())
    _check_existing_run(tmp_path, _run_record(Config(), "train", 0))  # no error: a resume
    speckled = config_from_dict({"sensor": {"speckle_contrast": 0.3}})
    with pytest.raises(ConfigError, match=r"already holds scenes generated with different \[sensor\]"):
        _check_existing_run(tmp_path, _run_record(speckled, "train", 0))
    with pytest.raises(ConfigError, match="different base_seed"):
        _check_existing_run(tmp_path, _run_record(Config(), "train", 1))


def test_a_dataset_from_before_the_device_depth_table_resumes_while_the_engine_stays_off(tmp_path):
    record = _run_record(Config(), "train", 0)
    del record["config"]["device_depth"]  # generate.json of a dotsim without [device_depth]
    (tmp_path / RUN_FILE).write_text(json.dumps(record))
    _check_existing_run(tmp_path, _run_record(Config(), "train", 0))  # no error: a resume
    with pytest.raises(ConfigError, match=r"already holds scenes generated with different \[device_depth\]"):
        on = config_from_dict({"device_depth": {"engine": "structured_light"}})
        _check_existing_run(tmp_path, _run_record(on, "train", 0))
