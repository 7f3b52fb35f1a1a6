"""Generator config: every key validated before anything runs; errors name file, key, value, allowed."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from generator.config import (
    SECTIONS,
    ConfigError,
    check_output_dir,
    config_from_dict,
    config_reference_markdown,
    load_config,
)

REPO = Path(__file__).resolve().parents[1]
GENERATOR_CONFIGS = ["default.toml", "structure_core.toml", "kinect.toml", "tiny.toml"]


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "my.toml"
    path.write_text(text)
    return path


def error_of(tmp_path: Path, text: str) -> str:
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert str(path) in message  # every error names the file
    return message


@pytest.mark.parametrize("name", GENERATOR_CONFIGS)
def test_shipped_configs_load(name, tmp_path):
    # Shipped configs read the asset cache beside configs/ (../assets_cache, built by `make assets`),
    # which a fresh checkout lacks: load a copy that has an (empty) cache folder in that place.
    copy = tmp_path / "configs" / name
    copy.parent.mkdir()
    copy.write_text((REPO / "configs" / name).read_text())
    (tmp_path / "assets_cache").mkdir()
    config = load_config(copy)
    assert config.source.endswith(name)


def test_missing_keys_take_defaults_and_to_dict_round_trips(tmp_path):
    config = load_config(write(tmp_path, "[scene]\nobject_count = [3, 7]\n"))
    assert config.scene.object_count == (3, 7)
    assert config.render.samples == 1  # default
    # A file that spells out every resolved value loads to the same config.
    lines = []
    for section, values in config.to_dict().items():
        if section == "source":
            continue
        lines.append(f"[{section}]")
        for key, value in values.items():
            lines.append(f"{key} = {value!r}".replace("'", '"'))
    again = load_config(write(tmp_path, "\n".join(lines) + "\n"))
    assert again.to_dict() == config.to_dict()


def test_unknown_key_suggests_closest(tmp_path):
    message = error_of(tmp_path, "[scene]\nobject_cont = [1, 2]\n")
    assert 'unknown key "object_cont"' in message and 'did you mean "object_count"' in message
    message = error_of(tmp_path, "[sensr]\ngain = 1.0\n")
    assert "[sensr]" in message and 'did you mean "[sensor]"' in message


def test_wrong_type(tmp_path):
    message = error_of(tmp_path, "[render]\nsamples = 1.5\n")
    assert "[render] samples = 1.5" in message and "wrong type" in message and "integer" in message
    message = error_of(tmp_path, "[render]\nsamples = true\n")
    assert "wrong type (bool)" in message
    message = error_of(tmp_path, '[scene]\ndistance = "far"\n')
    assert "[scene] distance" in message and "two-element array" in message


def test_out_of_range(tmp_path):
    message = error_of(tmp_path, "[rig]\nscale = 0\n")
    assert "[rig] scale = 0" in message and "out of range" in message and "0.02 <= x <= 1" in message
    message = error_of(tmp_path, "[scene]\nobject_count = [500, 100]\n")
    assert "low > high" in message
    message = error_of(tmp_path, '[sensor]\nexposure = "autom"\n')
    assert 'did you mean "auto"' in message and '"fixed", "auto"' in message
    message = error_of(tmp_path, '[scene]\nshapes = ["box", "cube"]\n')
    assert "'cube'" in message


def test_missing_pattern_file(tmp_path):
    message = error_of(tmp_path, '[pattern]\nsource = "file"\npath = "nope.png"\n')
    # Relative paths resolve against the config file's directory.
    assert str(tmp_path / "nope.png") in message and "file not found" in message
    message = error_of(tmp_path, '[pattern]\nsource = "file"\n')
    assert "[pattern] path is empty" in message


def test_missing_asset_dir(tmp_path):
    message = error_of(tmp_path, '[assets]\nsource = "cache"\ncache_dir = "no_cache"\n')
    assert "[assets] cache_dir" in message and "no_cache" in message and "dotsim assets build" in message


def test_unreadable_and_invalid_files(tmp_path):
    with pytest.raises(ConfigError, match="config file not found"):
        load_config(tmp_path / "absent.toml")
    assert "not valid TOML" in error_of(tmp_path, "[scene\n")


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


def test_every_key_documented():
    doc = (REPO / "docs" / "CONFIG.md").read_text()
    assert doc.strip() == config_reference_markdown().strip(), \
        "docs/CONFIG.md is stale: python -m generator.config > docs/CONFIG.md"
    for name, cls in SECTIONS.items():
        assert f"## [{name}]" in doc
        for f in dataclasses.fields(cls):
            assert f"| `{f.name}` |" in doc


def test_defaults_are_valid():
    # Every default passes its own rule (a default outside its range would be a silent bug).
    data = {name: {f.name: (list(f.default) if isinstance(f.default, tuple) else f.default)
                   for f in dataclasses.fields(cls) if f.default != ""}
            for name, cls in SECTIONS.items()}
    assert config_from_dict(data).to_dict() == config_from_dict({}).to_dict() | {"source": "<dict>"}
