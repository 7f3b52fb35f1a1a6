"""index.json and shard.json are checked before use (dotsim.dataset.layout.parse_index, parse_shard;
issue 37, item 8): every malformed shape, and an export folder given as a dataset, is one FormatError
line naming the file and the key, from the reader, from verify and from the commands."""

from __future__ import annotations

import hashlib
import json
import re
import shutil

import pytest

from commands.cli import main
from dotsim import dataset as ds
from dotsim.oracle_dataset import make_dataset
from dotsim.shards.writer import export_webdataset
from tests.output_folders import assert_one_line_error


@pytest.fixture(scope="module")
def sealed(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("layout") / "data", scenes=1, frames_per_scene=1)


def changed_copy(sealed, tmp_path, name: str, change) -> tuple:
    """A copy of the sealed dataset whose file `name` (index.json or the shard's shard.json) is
    change(its dict) written back, or change itself when it is a string (the file's new text)."""
    data = tmp_path / "data"
    shutil.copytree(sealed, data)
    path = data / name
    text = change if isinstance(change, str) else json.dumps(change(json.loads(path.read_text())))
    path.write_text(text)
    return data, path


SHA = "0" * 64
INDEX_CASES = {
    "files not a mapping": (lambda i: {**i, "files": []}, "'files' must map top-level file names"),
    "a file outside the dataset": (lambda i: {**i, "files": {"../x": SHA}}, "'files' must map"),
    "shards not a list": (lambda i: {**i, "shards": {"a": 1}}, "key 'shards' must be list, found dict"),
    "a shard not a mapping": (lambda i: {**i, "shards": [5]}, r"shards\[0\] = 5; allowed"),
    "a shard without a name": (lambda i: {**i, "shards": [{"sha256": SHA, "scene_count": 1}]},
                               r"shards\[0\] = .*; allowed: \{name: shard_NNNNN"),
    "a shard named as a file": (lambda i: {**i, "shards": [{**i["shards"][0], "name": "index.json"}]},
                                r"shards\[0\] = .*allowed"),
    "a count that is no integer": (lambda i: {**i, "shards": [{**i["shards"][0], "scene_count": "1"}]},
                                   r"shards\[0\] = .*allowed"),
    "a key given twice": ('{"format_version": "2.0", "format_version": "2.0", "shards": []}',
                          "key 'format_version' is given twice"),
}


@pytest.mark.parametrize("case", INDEX_CASES)
def test_a_malformed_index_json_is_one_line_everywhere(sealed, tmp_path, capsys, case):
    change, message = INDEX_CASES[case]
    data, path = changed_copy(sealed, tmp_path, ds.INDEX_FILE, change)
    with pytest.raises(ds.FormatError, match=rf"^{path}: {message}"):
        ds.open_dataset(data)
    report = ds.verify_dataset(data)  # the index named first; its scenes are then unsealed
    assert report.problems[0].path == path and re.match(message, report.problems[0].what), report.problems
    for command in (["stats", str(data), "-o", str(tmp_path / "s.png")],
                    ["export", str(data), str(tmp_path / "export")]):
        assert main(command) == 1
        err = capsys.readouterr().err
        assert_one_line_error(err, path)


SHARD_CASES = {
    "scenes not a list": (lambda s: {**s, "scenes": 3}, "key 'scenes' must be list"),
    "a scene not a mapping": (lambda s: {**s, "scenes": ["scene_0000000"]}, r"scenes\[0\] = .*allowed"),
    "a scene without its files": (
        lambda s: {**s, "scenes": [{k: v for k, v in s["scenes"][0].items() if k != "files"}]},
        r"scenes\[0\] = .*allowed"),
    "a scene file outside its folder": (
        lambda s: {**s, "scenes": [{**s["scenes"][0], "files": {"../../index.json": SHA}}]},
        r"scenes\[0\] = .*allowed"),
    "a negative index": (lambda s: {**s, "scenes": [{**s["scenes"][0], "scene_index": -1}]},
                         r"scenes\[0\] = .*allowed"),
}


@pytest.mark.parametrize("case", SHARD_CASES)
def test_a_malformed_shard_json_is_one_line(sealed, tmp_path, case):
    """(The reader checks a shard.json's sha256 against index.json first; a hand-edited one fails
    that, so the shape is checked on a dataset sealed again around it: index.json vouching for it.)"""
    change, message = SHARD_CASES[case]
    name = f"{ds.shard_name(0)}/{ds.SHARD_FILE}"
    data, path = changed_copy(sealed, tmp_path, name, change)
    index = json.loads((data / ds.INDEX_FILE).read_text())
    index["shards"][0]["sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    (data / ds.INDEX_FILE).write_text(json.dumps(index))
    with pytest.raises(ds.FormatError, match=rf"^{path}: {message}"):
        ds.open_dataset(data)
    problems = ds.verify_dataset(data).problems
    assert any(p.path == path and "not a valid shard.json" in p.what for p in problems), problems


def test_an_export_folder_given_as_a_dataset_says_what_it_is(sealed, tmp_path, capsys):
    export = export_webdataset(sealed, tmp_path / "export").out
    with pytest.raises(ds.FormatError, match=rf"^{export / 'index.json'}: format 'dotsim-webdataset' is not "
                                             r"a dotsim dataset's index.json; a folder of `dotsim export`"):
        ds.open_dataset(export)
    assert main(["stats", str(export), "-o", str(tmp_path / "s.png")]) == 0  # stats reads exports too
    capsys.readouterr()
    assert main(["verify", str(export)]) == 2
    assert_one_line_error(capsys.readouterr().err, export)
