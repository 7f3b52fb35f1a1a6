"""The `dotsim` program's parser (commands/cli.py): every numeric option of every command is
range-checked by argparse, with the allowed range in the message, before the command runs (issue 37,
item 6)."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import pytest

from commands.cli import COMMANDS, build_parser, main

REPO = Path(__file__).resolve().parents[2]


def options(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """(command path, action) of every option of every (sub)command."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from options(sub, (*path, name))
        elif action.option_strings:
            yield path, action


def test_no_numeric_option_is_left_unchecked():
    """A bare int or float type takes -1, 0, 1e400 or nan as they come; every numeric option has an
    option_types type instead."""
    unchecked = [f"dotsim {' '.join(path)} {action.option_strings[-1]}"
                 for path, action in options(build_parser()) if action.type in (int, float)]
    assert not unchecked, unchecked


def test_every_checked_option_refuses_what_no_number_is():
    checked = [action for _, action in options(build_parser())
               if getattr(action.type, "__module__", None) == "dotsim.option_types"]
    assert len(checked) > 40, len(checked)
    for action in checked:
        for text in ("nan", "1e400", "x"):
            with pytest.raises(argparse.ArgumentTypeError, match=rf"^'{text}': allowed: (an integer|a num)"):
                action.type(text)


@pytest.mark.parametrize("argv, option, allowed", [
    (["capture", "import", "--on", "a", "--off", "b", "--out", "o", "--scenes-per-shard", "0"],
     "--scenes-per-shard", "an integer >= 1 and <= 100000"),
    (["stats", "data", "-o", "s.png", "--max-frames", "-1"], "--max-frames", "an integer >= 0"),
    (["eval", "--checkpoint", "c.pt", "--data", "d", "--out", "e", "--max-frames", "-1"], "--max-frames",
     "an integer >= 0"),
    (["train", "--config", "train_tiny", "--data", "d", "--out", "r", "--minutes", "-5"], "--minutes",
     "a number >= 0"),
    (["capture", "info", "--device", "opencv:0", "-o", "r.json", "--max-depth", "0.1"], "--max-depth",
     "a number >= 0.5 and <= 1000"),
    (["show", "data", "--tile-width", "8"], "--tile-width", "an integer >= 16"),
    (["pattern", "make", "-o", "p.png", "--density", "0"], "--density", "a number > 0 and <= 0.2"),
])
def test_an_option_out_of_range_is_refused_before_the_command_runs(tmp_path, monkeypatch, capsys, argv,
                                                                   option, allowed):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as caught:
        main(argv)
    assert caught.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.endswith(f"argument {option}: '{argv[argv.index(option) + 1]}': allowed: {allowed}"), err
    assert not any(tmp_path.iterdir())  # nothing written


def test_commands_name_each_module_by_the_commands_it_adds():
    """COMMANDS is what main uses to import one module per run: each module adds exactly the
    commands COMMANDS gives it, and the full parser has every command."""
    assert list(_subparsers(build_parser())) == list(COMMANDS)
    for module in set(COMMANDS.values()):
        mine = [command for command, name in COMMANDS.items() if name == module]
        assert list(_subparsers(build_parser(mine[0]))) == mine, module


def test_a_run_imports_its_own_command_only():
    """`dotsim generate` builds no other stage's parser: torch (the trainer's), trimesh (the asset
    builder's) and OpenCV (show's) stay unimported, in a process of its own."""
    code = ("import sys; from commands.cli import build_parser; build_parser('generate'); "
            "print(sorted({'torch', 'trimesh', 'cv2', 'scipy'} & set(sys.modules)))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                          env={**os.environ, "PYTHONPATH": str(REPO)}, cwd=REPO)
    assert done.stdout.strip() == "[]", done.stdout


def _subparsers(parser: argparse.ArgumentParser) -> dict:
    return next(a.choices for a in parser._actions if isinstance(a, argparse._SubParsersAction))
