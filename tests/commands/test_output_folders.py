"""Every command in commands/ that writes: a read-only, missing or full output folder is one line
naming the path and exit status 1, and nothing half-written stays behind (issue 37, item 1)."""

from __future__ import annotations

from pathlib import Path

import pytest

from commands.cli import main
from dotsim.oracle_dataset import make_dataset
from tests.output_folders import assert_one_line_error, leftovers, read_only


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("out") / "data", scenes=2, frames_per_scene=2)


# command -> (argv given the dataset and the output file); each writes exactly that one file (and
# stats and pattern make a .json beside it)
WRITERS = {
    "show": lambda data, out: ["show", data, "-o", out.with_suffix(".png")],
    "show --overview": lambda data, out: ["show", data, "--overview", "-o", out.with_suffix(".png")],
    "show --ply": lambda data, out: ["show", data, "--ply", out.with_suffix(".ply")],
    "stats": lambda data, out: ["stats", data, "-o", out.with_suffix(".png")],
    "pattern make": lambda data, out: ["pattern", "make", "--scale", "0.05", "-o", out.with_suffix(".png")],
    "view --save": lambda data, out: ["view", data, "--frame", "0", "--save", out.with_suffix(".rrd")],
}


# `dotsim pattern make` makes its output's folder (a pattern is stored beside what uses it).
MAKES_ITS_FOLDER = {"pattern make"}


def written(argv) -> str:
    return str(argv[argv.index("-o") + 1] if "-o" in argv else argv[-1])


@pytest.mark.parametrize("command", WRITERS)
def test_read_only_folder(command, dataset, read_only_folder, capsys):
    argv = WRITERS[command](dataset, read_only_folder / "out")
    assert main(list(map(str, argv))) == 1
    assert_one_line_error(capsys.readouterr().err, written(argv), "read-only")
    assert not any(read_only_folder.iterdir())


@pytest.mark.parametrize("command", WRITERS)
def test_missing_folder(command, dataset, tmp_path, capsys):
    argv = WRITERS[command](dataset, tmp_path / "no" / "such" / "out")
    if command in MAKES_ITS_FOLDER:
        assert main(list(map(str, argv))) == 0 and Path(written(argv)).is_file()
        return
    assert main(list(map(str, argv))) == 1
    assert_one_line_error(capsys.readouterr().err, written(argv), f"no folder {tmp_path / 'no' / 'such'}")
    assert not (tmp_path / "no").exists()


@pytest.mark.parametrize("command", WRITERS)
def test_full_disk(command, dataset, tmp_path, no_space, capsys):
    argv = WRITERS[command](dataset, tmp_path / "out")
    assert main(list(map(str, argv))) == 1
    assert_one_line_error(capsys.readouterr().err, "no space left on device")
    assert not leftovers(tmp_path) and not (tmp_path / written(argv)).exists()


@pytest.mark.parametrize("command", [["seal"], ["verify", "--repair"]])
def test_a_read_only_dataset_is_one_line(command, tmp_path, capsys):
    """seal and repair write into the dataset itself."""
    data = make_dataset(tmp_path / "data", scenes=1, frames_per_scene=1)
    (data / "index.json").unlink()  # something for them to write
    with read_only(data):
        assert main([*command[:1], str(data), *command[1:]]) == 1
        assert_one_line_error(capsys.readouterr().err, data, "read-only")
