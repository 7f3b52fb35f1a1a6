"""Generator and trainer configs (one engine, dotsim.config_schema): every key validated before anything
runs; errors name file, key, value and what is allowed; the reference docs match the schemas."""

from __future__ import annotations

import dataclasses
import json
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

import pytest

import generator.config as generator_config
import trainer.config as trainer_config
from commands.cli import main as cli_main
from dotsim import config_schema
from dotsim.config_schema import FloatRange, setting
from dotsim.configs import BUILTIN_DIR, builtin_names
from dotsim.rig.config import RigConfig
from generator.config import ConfigError, check_output_dir, config_json, load_config

REPO = Path(__file__).resolve().parents[2]
GENERATOR_CONFIGS = ["default.toml", "structure_core.toml", "kinect.toml", "realsense_d415.toml",
                     "realsense_d435.toml", "tiny.toml", "bench_accuracy.toml", "table2.toml"]
TRAINER_CONFIGS = ["train_tiny.toml", "train_cpu.toml", "train_gigadepth.toml", "train_table2.toml"]
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


@pytest.fixture
def builtin_cwd(tmp_path, monkeypatch):
    """A current directory as a built-in config expects it: its paths are relative to it, as the
    cache_dir ("assets_cache", where `dotsim assets build` writes the cache: an empty one stands in)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "assets_cache").mkdir()
    return tmp_path


@pytest.mark.parametrize("name", GENERATOR_CONFIGS)
def test_shipped_generator_configs_load_as_written(name, builtin_cwd):
    tmp_path = builtin_cwd  # built-in configs are loaded by name
    config = load_config(Path(name).stem)
    path = BUILTIN_DIR / name
    assert config.source == str(path)
    resolved = config.to_dict()
    for (table, key), value in values_in_file(path).items():
        if key in ("cache_dir", "file", "path"):
            assert resolved[table][key] == str((tmp_path / value).resolve())
        else:
            assert resolved[table][key] == value, (table, key)
            assert type(resolved[table][key]) is type(value) or isinstance(value, int), (table, key)


def test_builtin_configs_by_name_and_config_show(tmp_path, capsys):
    assert builtin_names() == sorted(Path(name).stem for name in GENERATOR_CONFIGS + TRAINER_CONFIGS)
    assert load_config("tiny") == load_config(BUILTIN_DIR / "tiny.toml")
    train_tiny = trainer_config.load_config(BUILTIN_DIR / "train_tiny.toml")
    assert trainer_config.load_config("train_tiny") == train_tiny
    assert cli_main(["config", "show", "tiny"]) == 0
    assert capsys.readouterr().out == (BUILTIN_DIR / "tiny.toml").read_text()
    assert cli_main(["config", "show", "tinny"]) == 2
    error = capsys.readouterr().err
    assert "config 'tinny': no built-in config of that name; allowed: bench_accuracy" in error
    # a copy elsewhere is a file like any other: relative paths are relative to it
    (tmp_path / "mine.toml").write_text((BUILTIN_DIR / "tiny.toml").read_text())
    assert load_config(tmp_path / "mine.toml").rig == load_config("tiny").rig
    with pytest.raises(ConfigError, match="nothere.toml: config file not found"):
        load_config("nothere.toml")


@pytest.mark.parametrize("name", GENERATOR_CONFIGS)
def test_a_saved_config_loads_back_equal(name, builtin_cwd):
    """config_json -> load_config is the identity on every shipped config, `source` included; the
    saved file's own folder plays no part (its paths are absolute)."""
    tmp_path = builtin_cwd
    config = load_config(BUILTIN_DIR / name)
    saved = tmp_path / "elsewhere" / "saved.json"
    saved.parent.mkdir()
    saved.write_bytes(config_json(config))
    loaded = load_config(saved)
    assert loaded == config and loaded.to_dict() == config.to_dict()
    assert json.loads(saved.read_bytes())["source"] == str(BUILTIN_DIR / name)


@pytest.mark.parametrize("text, problem", [
    ("{not json", "not valid JSON"), ("[1, 2]", "not a saved config"), ('{"rig": {}}', "not a saved config"),
    ('{"source": "x", "rig": {"scale": 7}}', r"x: \[rig\] scale = 7")])
def test_a_bad_saved_config_is_one_error_naming_it(tmp_path, text, problem):
    path = tmp_path / "saved.json"
    path.write_text(text)
    with pytest.raises(ConfigError, match=problem) as info:
        load_config(path)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("name", TRAINER_CONFIGS)
def test_shipped_trainer_configs_load_as_written(name):
    path = BUILTIN_DIR / name
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


# (config, file text, fragments the error must contain): the file is named by error_of.
GEN, TRAIN = "generator", "trainer"
ERROR_CASES = [
    # unknown keys and tables, with the closest valid one
    (GEN, "[scene]\nobject_cont = [1, 2]\n", ['unknown key "object_cont"', 'did you mean "object_count"']),
    (GEN, "[sensr]\ngain = 1.0\n", ["[sensr]", 'did you mean "[sensor]"']),
    (TRAIN, "[model]\nclasess = [4, 4]\n", ['[model] unknown key "clasess" (did you mean "classes"?)']),
    (TRAIN, "sed = 3\n", ['unknown key "sed" (did you mean "seed"?); valid keys: seed, [model], [data], '
                          "[train]"]),
    (TRAIN, "[modle]\nlines = 2\n", ['did you mean "[model]"']),
    (TRAIN, "[scene]\nobject_count = [1, 2]\n", ['unknown key "[scene]"; valid keys: seed, [model]']),
    (TRAIN, "model = 3\n", ["model = 3: expected a [model] table"]),
    # wrong types
    (GEN, "[render]\nsamples = 1.5\n", ["[render] samples = 1.5", "wrong type", "integer"]),
    (GEN, "[render]\nsamples = true\n", ["wrong type (bool)"]),
    (GEN, '[scene]\ndistance = "far"\n', ["[scene] distance", "two-element array"]),
    (TRAIN, "[train]\nlr = 'fast'\n", ["[train] lr = 'fast': wrong type (str); allowed: a number, 0 < x"]),
    (TRAIN, "[train]\namp = 1\n", ["[train] amp = 1: wrong type (int)", '"off", "float16", "bfloat16"']),
    (TRAIN, '[train]\namp = "bf16"\n', ['[train] amp = \'bf16\': not a valid choice']),
    (TRAIN, "[model]\nclasses = [4, 'a']\n", ["[model] classes = [4, 'a']: entry 'a': wrong type (str)"]),
    (TRAIN, "[model]\nstage_inputs = [[0, 8], [0, 8, 1]]\n",
     ["entry [0, 8, 1]: wrong type (expected a two-element array)"]),
    (TRAIN, "[model]\nclassifier_hidden = [[8], 8]\n", ["entry 8: wrong type (int; expected an array)"]),
    # out of range, not a choice
    (GEN, "[rig]\nscale = 0\n", ["[rig] scale = 0", "out of range", "0.02 <= x <= 1"]),
    (GEN, "[scene]\nobject_count = [500, 100]\n", ["low > high"]),
    (GEN, '[sensor]\nexposure = "autom"\n', ['did you mean "auto"', '"fixed", "auto"']),
    (GEN, '[scene]\nshapes = ["box", "cube"]\n', ["'cube'"]),
    (GEN, "[scene]\nshapes = []\n", ["needs at least 1 entry", "a non-empty list of"]),
    (GEN, "[scene]\nroom_size = [6, 8]\nback_wall_distance = [3, 6]\n",
     ["[scene] back_wall_distance = [3.0, 6.0]", "0 < low <= high < the smallest room_size (6 m)"]),
    (GEN, "[scene]\nback_wall_distance = [0, 3]\n", ["[scene] back_wall_distance = [0.0, 3.0]"]),
    (TRAIN, "seed = -1\n", ["seed = -1: out of range; allowed: an integer, 0 <= x <= 4294967295"]),
    (TRAIN, "[model]\ncolumn_padding = 0.5\n",
     ["[model] column_padding = 0.5: out of range; allowed: a number, 0 <= x < 0.5"]),
    (TRAIN, '[train]\noptimizer = "adamm"\n',
     ['not a valid choice (did you mean "adam"?); allowed: one of "sgd", "adam"']),
    (TRAIN, "[model]\nclasses = [4, 1]\n",
     ["classes = [4, 1]: entry 1: out of range; allowed: a non-empty list of integers, each 2 <= x"]),
    (TRAIN, "[data]\nintensity_scale = [1.2, 0.8]\n", ["intensity_scale = [1.2, 0.8]: low > high"]),
    # the trainer's rules spanning keys
    (TRAIN, "[model]\nclasses = [4, 4]\noverlaps = [0, 5]\nclassifier_hidden = [[], []]\n"
            "stage_inputs = [[0, 8], [0, 8], [0, 8]]\n",
     ["[model] overlaps = [0, 5]: does not fit classes = [4, 4]"]),
    (TRAIN, "[model]\nbackbone_kernels = [5, 3, 3, 3, 3, 5, 3, 4]\n",
     ["[model] backbone_kernels = [5, 3, 3, 3, 3, 5, 3, 4]: an even kernel size"]),
    (TRAIN, "[model]\nbackbone_kernels = [5]\n",
     ["not one per backbone channel entry; allowed: 8 odd kernel sizes"]),
    (TRAIN, "[model]\nstage_inputs = [[0, 64], [32, 64], [64, 64], [100, 64]]\n",
     ["slice [100, 64] is empty or exceeds the 160 backbone output channels"]),
    (TRAIN, "[data]\ncrop_height = 63\n", ["[data] crop_height = 63: odd"]),
    (TRAIN, "[train]\nce_weights = [1.0]\n",
     ["[train] ce_weights = [1.0]: not one weight per tree level; allowed: 3 weights"]),
    (TRAIN, "[model]\nlcn_window = 10\n", ["[model] lcn_window = 10: even"]),
    # settings that contradict each other (issue 45 items 5, 9, 10 and the preset's max_depth)
    (GEN, "[scene]\ndistance = [1.0, 3.0]\nback_wall_distance = [0.5, 0.8]\nroom_size = [4, 6]\n",
     ["[scene] back_wall_distance = [0.5, 0.8] is not beyond [scene] distance = [1.0, 3.0]",
      "allowed: back_wall_distance low > 1.05 m"]),
    (GEN, "[rig]\nbaseline = -0.05\n",
     ["[rig]: the projector's x offset (baseline) is -0.05 m; allowed: > 0"]),
    (TRAIN, "[model]\nstride = 0\n", ["[model] stride = 0: not a valid choice; allowed: one of 1, 2"]),
    (TRAIN, "[model]\nstride = 100\n", ["[model] stride = 100: not a valid choice"]),
]


@pytest.mark.parametrize(("which", "text", "fragments"), ERROR_CASES)
def test_errors_name_key_value_and_what_is_allowed(which, text, fragments, tmp_path):
    message = error_of(tmp_path, text, load_config if which == GEN else trainer_config.load_config)
    for fragment in fragments:
        assert fragment in message


def test_checkpoint_configs_with_tuples_load():
    # Checkpoints of earlier versions stored the config with tuples (dataclasses.asdict).
    config = trainer_config.load_config("train_cpu")
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


@dataclass(frozen=True)
class PointTable:
    centre: tuple[float, float] = setting((1.0, 0.5), "a pair such as a principal point", low=0.0)
    span: FloatRange = setting((0.0, 1.0), "a range", low=0.0)
    file: str = setting("", "a file", path=True)


@dataclass(frozen=True)
class PointConfig:
    point: PointTable = field(default_factory=PointTable)


def test_a_new_key_is_one_declaration(tmp_path):
    # A pair is not a range (its entries need no order); paths resolve against the file's folder.
    config = config_schema.from_dict(PointConfig, {"point": {"centre": [3, 2.5], "file": "a.png"}}, "p.toml",
                                     base_dir=tmp_path)
    assert config.point == PointTable(centre=(3.0, 2.5), file=str(tmp_path / "a.png"))
    with pytest.raises(ConfigError, match=r"p\.toml: \[point\] span = \[2, 1\]: low > high"):
        config_schema.from_dict(PointConfig, {"point": {"span": [2, 1]}}, "p.toml")
    with pytest.raises(ConfigError, match=r"centre = \[1\]: wrong type \(expected a two-element array\); "
                                          r"allowed: a \[number, number\] pair, each 0 <= x"):
        config_schema.from_dict(PointConfig, {"point": {"centre": [1]}}, "p.toml")
    doc = config_schema.reference_markdown(PointConfig, "Points", "Intro.")
    assert "| `centre` | [float, float] pair | a [number, number] pair, each 0 <= x | `[1, 0.5]` |" in doc
    assert "| `span` | range of floats | [low, high], two numbers with low <= high, each 0 <= x |" in doc
    assert config_schema.to_dict(config) == {"point": {"centre": [3.0, 2.5], "span": [0.0, 1.0],
                                                       "file": str(tmp_path / "a.png")}}


@dataclass(frozen=True)
class Pose(config_schema.Checked):
    name: str = setting(config_schema.REQUIRED, "a name", min_items=1)
    offset: tuple[float, float, float] | None = setting(None, "three numbers or none")
    depth: float = setting(1.0, "a depth", low=0.0, low_open=True)


def test_records_are_checked_on_construction_and_read_whole_from_json():
    # Construction in code is held to the declared rule, with the file's wording and normalisation.
    assert Pose("a", [1, 2, 3]) == Pose("a", (1.0, 2.0, 3.0)) and type(Pose("a", depth=2).depth) is float
    assert Pose("a", offset=None).offset is None
    with pytest.raises(ConfigError, match=r"^Pose.depth = 0: out of range; allowed: a number, 0 < x$"):
        Pose("a", depth=0)
    with pytest.raises(ConfigError, match=r"^Pose.offset = \[1, 2\]: wrong type .*; allowed: a list of 3 "
                                          r"numbers, or null$"):
        Pose("a", offset=(1, 2))
    with pytest.raises(ConfigError, match=r"^Pose.name = '': empty; allowed: a non-empty string$"):
        Pose("")
    with pytest.raises(ConfigError, match=r"^Pose.depth = True: wrong type \(bool\)"):
        Pose("a", depth=True)
    np = pytest.importorskip("numpy")
    assert Pose("a", depth=np.float32(0.5)).depth == 0.5  # numpy scalars are numbers
    # the generator's and trainer's tables too
    with pytest.raises(ConfigError, match=r"^RigConfig.scale = 2.0: out of range; allowed: a number, "
                                          r"0.02 <= x <= 1$"):
        RigConfig(scale=2.0)
    with pytest.raises(ConfigError, match=r"^DataConfig.workers = -1: out of range"):
        trainer_config.DataConfig(workers=-1)
    # From JSON every field must be given, except those named optional; errors name where.key.
    read = config_schema.record_from_dict
    assert read(Pose, {"name": "a", "offset": [0, 0, 1]}, "pose", optional=("depth",)) == Pose("a", (0, 0, 1))
    with pytest.raises(ConfigError, match=r"^pose.offset is missing$"):
        read(Pose, {"name": "a", "depth": 1.0}, "pose")
    with pytest.raises(ConfigError, match=r'^pose: unknown key "dpeth" \(did you mean "depth"\?\)'):
        read(Pose, {"name": "a", "offset": None, "depth": 1.0, "dpeth": 2}, "pose")
    with pytest.raises(ConfigError, match=r"^pose.depth = -1: out of range"):
        read(Pose, {"name": "a", "offset": None, "depth": -1}, "pose")
    with pytest.raises(ConfigError, match=r"^pose = 3: not a mapping"):
        read(Pose, 3, "pose")


def test_max_depth_left_out_is_the_rigs_own_and_follows_rig(tmp_path):
    """Issue 45: a realsense_d415 config without max_depth rendered to 20 m while the preset (and data
    imported with --rig realsense_d415) says 10 m."""
    from dotsim.rig.config import read_rig_config
    from dotsim.rig.options import with_rig_options

    path = write(tmp_path, '[rig]\npreset = "realsense_d415"\n')
    config = load_config(path)
    assert config.rig.max_depth == 10.0 == config.calibrated_rig.rig.max_depth
    assert read_rig_config(path)[0].max_depth == 10.0  # `--rig my.toml` and `rig show my.toml` alike
    base, source = read_rig_config("structure_core")  # [rig] alone: CI has no asset cache built
    settings, calibrated = with_rig_options(base, source, "kinect_v1")
    assert settings.max_depth == 8.0 == calibrated.rig.max_depth
    apart = replace(base, max_depth=7.0)  # set apart from the preset's: stays
    assert with_rig_options(apart, source, "kinect_v1")[1].rig.max_depth == 7.0


def test_a_rig_file_of_zero_baseline_is_refused(tmp_path):
    """Issue 45 item 9: a zero baseline gave disparity 0 everywhere while 62 % of pixels were marked
    visible."""
    from dataclasses import replace

    from dotsim.rig.files import rig_file_json
    from dotsim.rig.presets import get_preset

    rig = get_preset("structure_core")
    (tmp_path / "flat.json").write_bytes(rig_file_json(replace(rig, projector_translation=(0.0, 0.0, 0.0))))
    message = error_of(tmp_path, f'[rig]\nfile = "{tmp_path / "flat.json"}"\n')
    assert "my.toml: [rig]: the projector's x offset (baseline) is 0 m; allowed: > 0" in message
