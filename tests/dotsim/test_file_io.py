"""dotsim.file_io: the one atomic writer and the checksums every writer in dotsim uses."""

import doctest
import errno
import hashlib
import json
import pickle

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


def test_a_write_into_a_read_only_folder_is_a_write_error_naming_the_file(read_only_folder):
    """The failed write's cleanup (removing a temporary file that is not there) fails again on a
    read-only filesystem; the error reported is the write's own, one line naming the file."""
    path = read_only_folder / "a.json"
    with pytest.raises(file_io.WriteError) as caught:
        file_io.atomic_write_json(path, {"a": 1})
    assert str(caught.value).startswith(f"{path}: cannot write it: ") and "\n" not in str(caught.value)
    assert "read-only" in str(caught.value) or "no permission" in str(caught.value)
    assert not any(read_only_folder.iterdir())


def test_a_write_into_a_missing_folder_or_a_file_names_it(tmp_path):
    with pytest.raises(file_io.WriteError, match=f"no folder {tmp_path / 'none'}"):
        file_io.atomic_write_bytes(tmp_path / "none" / "a.bin", b"x")
    (tmp_path / "file").write_bytes(b"")
    with pytest.raises(file_io.WriteError, match=f"{tmp_path / 'file'} is a file, not a folder"):
        file_io.atomic_write_bytes(tmp_path / "file" / "sub" / "a.bin", b"x")
    with pytest.raises(file_io.WriteError, match="is a file, not a directory"):
        file_io.check_writable_folder(tmp_path / "file" / "out", "--out")
    with pytest.raises(file_io.WriteError, match=f"{tmp_path / 'file' / 'out'}: cannot write it: "
                                                  f"{tmp_path / 'file'} is a file"):
        file_io.make_folder(tmp_path / "file" / "out")


def test_an_error_of_the_callers_own_passes_unchanged(tmp_path):
    """Only the writer's own file operations become WriteError: an OSError the caller's code raises
    inside the block (reading its input) is its own."""
    with pytest.raises(FileNotFoundError), file_io.atomic_writer(tmp_path / "out.bin") as stream:
        stream.write((tmp_path / "missing-input").read_bytes())
    assert not any(tmp_path.iterdir())


def test_write_error_pickles_and_check_writable_folder_leaves_nothing(tmp_path, read_only_folder):
    error = pickle.loads(pickle.dumps(file_io.WriteError("x: cannot write it", errno.EROFS)))
    assert str(error) == "x: cannot write it" and error.errno == errno.EROFS
    assert file_io.check_writable_folder(tmp_path / "new" / "dir", "--out") == tmp_path / "new" / "dir"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["read_only"]
    with pytest.raises(file_io.WriteError, match=f"--out {read_only_folder / 'x'}: {read_only_folder} is not "
                                                  "writable"):
        file_io.check_writable_folder(read_only_folder / "x", "--out")
