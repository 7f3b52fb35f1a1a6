"""dotsim.file_io: the one atomic writer and the checksums every writer in dotsim uses."""

import doctest
import hashlib
import json

import pytest

from dotsim import file_io, pattern_store


@pytest.mark.parametrize("module", [file_io, pattern_store])
def test_docstring_examples(module):
    result = doctest.testmod(module)
    assert result.attempted > 0 and result.failed == 0


def test_atomic_write_replaces_whole_file_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "a.bin"
    path.write_bytes(b"old")
    file_io.atomic_write_bytes(path, b"new contents")
    assert path.read_bytes() == b"new contents"
    assert [p.name for p in tmp_path.iterdir()] == ["a.bin"]


def test_failed_write_keeps_the_old_file_and_removes_the_temporary(tmp_path):
    path = tmp_path / "a.json"
    path.write_bytes(b"old")
    with pytest.raises(RuntimeError, match="boom"), file_io.atomic_writer(path) as stream:
        stream.write(b"half")
        raise RuntimeError("boom")
    assert path.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]


def test_json_and_checksums_against_the_standard_library(tmp_path):
    obj = {"b": [1, 2.5], "a": {"z": None, "y": "text"}}
    path = file_io.atomic_write_json(tmp_path / "x.json", obj)
    assert json.loads(path.read_bytes()) == obj
    data = path.read_bytes()
    assert file_io.sha256_bytes(data) == hashlib.sha256(data).hexdigest() == file_io.sha256_file(path)
    with pytest.raises(ValueError):
        file_io.json_bytes({"nan": float("nan")})
