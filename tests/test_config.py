"""Generator and trainer configs (one engine, dotsim.config_schema): every key validated before anything
runs; errors name file, key, value and what is allowed; the reference docs match the schemas."""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

import pytest

import generator.config as generator_config
import trainer.config as trainer_config
from dotsim import config_schema
from generator.config import ConfigError, check_output_dir, load_config

REPO = Path(__file__).resolve().parents[1]
GENERATOR_CONFIGS = ["default.toml", "structure_core.toml", "kinect.toml", "tiny.toml", "bench_accuracy.toml"]
TRAINER_CONFIGS = ["train_tiny.toml", "train_cpu.toml", "train_gigadepth.toml"]
# (config module, its reference page)
CONFIGS = [(generator_config, "CONFIG.md"), (trainer_config, "TRAIN_CONFIG.md")]


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "my.toml"
    path.write_text(text)
    return path


def error_of(tmp_path: Path, text: str, load=load_config) -> str:
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load(path)
    message = str(info.value)
    assert str(path) in message  # every error names the file
    return message


def trainer_error(tmp_path: Path, text: str) -> str:
    return error_of(tmp_path, text, trainer_config.load_config)


def as_toml(data: dict) -> str:
    """A dict of top-level keys and tables written as TOML, independently of the engine's writer."""
    def value(v):
        if isinstance(v, bool):
            return str(v).lower()
        if isinstance(v, list | tuple):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return f'"{v}"' if isinstance(v, str) else repr(v)
    top = [f"{k} = {value(v)}" for k, v in data.items() if not isinstance(v, dict)]
    tables = [f"[{k}]\n" + "".join(f"{key} = {value(x)}\n" for key, x in v.items())
              for k, v in data.items() if isinstance(v, dict)]
    return "\n".join(top) + "\n" + "\n".join(tables)


def values_in_file(path: Path) -> dict:
    """(table, key) -> value as written in a TOML file, lists and all; table None for top-level keys."""
    data = tomllib.loads(path.read_text())
    flat = {}
    for name, table in data.items():
        for key, value in (table.items() if isinstance(table, dict) else [(name, table)]):
            flat[(name if isinstance(table, dict) else None, key)] = value
    return flat


@pytest.mark.parametrize("name", GENERATOR_CONFIGS)
def test_shipped_generator_configs_load_as_written(name, tmp_path):
    # Shipped configs read the asset cache beside configs/ (../assets_cache, built by `make assets`),
    # which a fresh checkout lacks: load a copy that has an (empty) cache folder in that place.
    copy = tmp_path / "configs" / name
    copy.parent.mkdir()
    copy.write_text((REPO / "configs" / name).read_text())
    (tmp_path / "assets_cache").mkdir()
    config = load_config(copy)
    assert config.source.endswith(name)
    resolved = config.to_dict()
    for (table, key), value in values_in_file(copy).items():
        if key == "cache_dir":
            assert resolved[table][key] == str((copy.parent / value).resolve())
        else:
            assert resolved[table][key] == value, (table, key)
            assert type(resolved[table][key]) is type(value) or isinstance(value, int), (table, key)


@pytest.mark.parametrize("name", TRAINER_CONFIGS)
def test_shipped_trainer_configs_load_as_written(name):
    path = REPO / "configs" / name
    resolved = trainer_config.load_config(path).to_dict()
    for (table, key), value in values_in_file(path).items():
        assert (resolved[key] if table is None else resolved[table][key]) == value, (table, key)


@pytest.mark.parametrize(("module", "load"), [(generator_config, load_config),
                                              (trainer_config, trainer_config.load_config)])
def test_missing_keys_take_defaults_and_to_dict_round_trips(module, load, tmp_path):
    key = {generator_config: "[scene]\nobject_count = [3, 7]\n", trainer_config: "[model]\nlines = 7\n"}
    config = load(write(tmp_path, key[module]))
    resolved = config.to_dict()
    resolved.pop("source", None)
    # A file that spells out every resolved value loads to the same config.
    again = load(write(tmp_path, as_toml(resolved)))
    assert again.to_dict() == config.to_dict()
    defaults = module.config_from_dict({}).to_dict()
    changed = [(t, k) for t, v in resolved.items() if isinstance(v, dict) for k in v
               if v[k] != defaults[t][k]]
    assert changed == ([("scene", "object_count")] if module is generator_config else [("model", "lines")])


def test_unknown_key_suggests_closest(tmp_path):
    message = error_of(tmp_path, "[scene]\nobject_cont = [1, 2]\n")
    assert 'unknown key "object_cont"' in message and 'did you mean "object_count"' in message
    message = error_of(tmp_path, "[sensr]\ngain = 1.0\n")
    assert "[sensr]" in message and 'did you mean "[sensor]"' in message
    message = trainer_error(tmp_path, "[model]\nclasess = [4, 4]\n")
    assert '[model] unknown key "clasess" (did you mean "classes"?)' in message
    message = trainer_error(tmp_path, "sed = 3\n")
    assert 'unknown key "sed" (did you mean "seed"?); valid keys: seed, [model], [data], [train]' in message
    message = trainer_error(tmp_path, "[modle]\nlines = 2\n")
    assert 'did you mean "[model]"' in message
    message = trainer_error(tmp_path, "[scene]\nobject_count = [1, 2]\n")  # a generator config
    assert 'unknown key "[scene]"; valid keys: seed, [model], [data], [train]' in message
    message = trainer_error(tmp_path, "model = 3\n")
    assert "model = 3: expected a [model] table" in message


def test_wrong_type(tmp_path):
    message = error_of(tmp_path, "[render]\nsamples = 1.5\n")
    assert "[render] samples = 1.5" in message and "wrong type" in message and "integer" in message
    message = error_of(tmp_path, "[render]\nsamples = true\n")
    assert "wrong type (bool)" in message
    message = error_of(tmp_path, '[scene]\ndistance = "far"\n')
    assert "[scene] distance" in message and "two-element array" in message
    message = trainer_error(tmp_path, "[train]\nlr = 'fast'\n")
    assert "[train] lr = 'fast': wrong type (str); allowed: a number, 0 < x" in message
    message = trainer_error(tmp_path, "[train]\namp = 1\n")
    assert "[train] amp = 1: wrong type (int); allowed: true or false" in message
    message = trainer_error(tmp_path, "[model]\nclasses = [4, 'a']\n")
    assert "[model] classes = [4, 'a']: entry 'a': wrong type (str)" in message
    message = trainer_error(tmp_path, "[model]\nstage_inputs = [[0, 8], [0, 8, 1]]\n")
    assert "entry [0, 8, 1]: wrong type (expected a two-element array)" in message
    message = trainer_error(tmp_path, "[model]\nclassifier_hidden = [[8], 8]\n")
    assert "entry 8: wrong type (int; expected an array)" in message
    message = trainer_error(tmp_path, "seed = -1\n")
    assert "seed = -1: out of range; allowed: an integer, 0 <= x <= 4294967295" in message


def test_out_of_range(tmp_path):
    message = error_of(tmp_path, "[rig]\nscale = 0\n")
    assert "[rig] scale = 0" in message and "out of range" in message and "0.02 <= x <= 1" in message
    message = error_of(tmp_path, "[scene]\nobject_count = [500, 100]\n")
    assert "low > high" in message
    message = error_of(tmp_path, '[sensor]\nexposure = "autom"\n')
    assert 'did you mean "auto"' in message and '"fixed", "auto"' in message
    message = error_of(tmp_path, '[scene]\nshapes = ["box", "cube"]\n')
    assert "'cube'" in message
    message = error_of(tmp_path, "[scene]\nshapes = []\n")
    assert "needs at least 1 entries" in message and "a non-empty list of" in message
    message = trainer_error(tmp_path, "[model]\ncolumn_padding = 0.5\n")
    assert "[model] column_padding = 0.5: out of range; allowed: a number, 0 <= x < 0.5" in message
    message = trainer_error(tmp_path, '[train]\noptimizer = "adamm"\n')
    assert 'not a valid choice (did you mean "adam"?); allowed: one of "sgd", "adam"' in message
    message = trainer_error(tmp_path, "[model]\nclasses = [4, 1]\n")
    assert "classes = [4, 1]: entry 1: out of range; allowed: a non-empty list of integers, each 2 <= x" \
        in message
    message = trainer_error(tmp_path, "[data]\nintensity_scale = [1.2, 0.8]\n")
    assert "intensity_scale = [1.2, 0.8]: low > high" in message


def test_trainer_cross_field_rules(tmp_path):
    message = trainer_error(tmp_path, "[model]\nclasses = [4, 4]\noverlaps = [0, 5]\n"
                            "classifier_hidden = [[], []]\nstage_inputs = [[0, 8], [0, 8], [0, 8]]\n")
    assert "[model] overlaps = [0, 5]: does not fit classes = [4, 4]" in message
    message = trainer_error(tmp_path, "[model]\nbackbone_kernels = [5, 3, 3, 3, 3, 5, 3, 4]\n")
    assert "[model] backbone_kernels = [5, 3, 3, 3, 3, 5, 3, 4]: an even kernel size" in message
    message = trainer_error(tmp_path, "[model]\nbackbone_kernels = [5]\n")
    assert "not one per backbone channel entry; allowed: 8 odd kernel sizes" in message
    message = trainer_error(tmp_path, "[model]\nstage_inputs = [[0, 64], [32, 64], [64, 64], [100, 64]]\n")
    assert "slice [100, 64] is empty or exceeds the 160 backbone output channels" in message
    message = trainer_error(tmp_path, "[data]\ncrop_height = 63\n")
    assert "[data] crop_height = 63: odd" in message
    message = trainer_error(tmp_path, "[train]\nce_weights = [1.0]\n")
    assert "[train] ce_weights = [1.0]: not one weight per tree level; allowed: 3 weights" in message
    message = trainer_error(tmp_path, "[model]\nlcn_window = 10\n")
    assert "[model] lcn_window = 10: even" in message


def test_checkpoint_configs_with_tuples_load():
    # Checkpoints of earlier versions stored the config with tuples (dataclasses.asdict).
    config = trainer_config.load_config(REPO / "configs" / "train_cpu.toml")
    as_tuples = dataclasses.asdict(config)
    assert isinstance(as_tuples["model"]["stage_inputs"][0], tuple)
    assert trainer_config.config_from_dict(as_tuples, "checkpoint") == config


def test_missing_pattern_file(tmp_path):
    message = error_of(tmp_path, '[pattern]\nsource = "file"\npath = "nope.png"\n')
    # Relative paths resolve against the config file's directory.
    assert str(tmp_path / "nope.png") in message and "file not found" in message
    message = error_of(tmp_path, '[pattern]\nsource = "file"\n')
    assert "[pattern] path is empty" in message


def test_missing_asset_dir(tmp_path):
    message = error_of(tmp_path, '[assets]\nsource = "cache"\ncache_dir = "no_cache"\n')
    assert "[assets] cache_dir" in message and "no_cache" in message and "dotsim assets build" in message


@pytest.mark.parametrize("load", [load_config, trainer_config.load_config])
def test_unreadable_and_invalid_files(load, tmp_path):
    with pytest.raises(ConfigError, match="absent.toml: config file not found"):
        load(tmp_path / "absent.toml")
    assert "not valid TOML" in error_of(tmp_path, "[scene\n", load)


def test_one_config_error():
    assert generator_config.ConfigError is trainer_config.ConfigError is config_schema.ConfigError


def test_unwritable_output(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    with pytest.raises(ConfigError, match="is a file, not a directory"):
        check_output_dir(blocker / "out")
    # /proc refuses new files even for root, unlike a chmod-ed directory.
    with pytest.raises(ConfigError, match="not writable"):
        check_output_dir("/proc/dotsim_out")
    assert check_output_dir(tmp_path / "new" / "dir") == tmp_path / "new" / "dir"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]  # the probe left nothing


@pytest.mark.parametrize(("module", "page"), CONFIGS)
def test_every_key_documented(module, page):
    doc = (REPO / "docs" / page).read_text()
    assert doc.strip() == module.config_reference_markdown().strip(), \
        f"docs/{page} is stale: python -m {module.__name__} > docs/{page}"
    for name, cls in config_schema.tables(module.Config).items():
        assert f"## [{name}]" in doc
        for f in dataclasses.fields(cls):
            assert f"| `{f.name}` |" in doc


@pytest.mark.parametrize(("module", "page"), CONFIGS)
def test_defaults_are_valid(module, page):
    # Every default passes its own rule (a default outside its range would be a silent bug).
    defaults = module.Config()
    data = {name: (value if not isinstance(value, dict) else
                   {k: v for k, v in value.items() if v != ""})  # empty paths stay unset
            for name, value in config_schema.to_dict(defaults).items()}
    assert module.config_from_dict(data, "<dict>") == module.config_from_dict({}, "<dict>")
