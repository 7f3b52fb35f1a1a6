"""The `dotsim` program's parser (commands/cli.py): every numeric option of every command is
range-checked by argparse, with the allowed range in the message, before the command runs (issue 37,
item 6); every command spells its output -o/--out (the earlier spellings still accepted), takes
--no-progress where it draws a bar, and takes the same things as --rig (issue 36, item 7)."""

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


def commands(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """(command path, parser) of every (sub)command that runs (no further subcommands)."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield path, parser
    for action in subs:
        for name, sub in action.choices.items():
            yield from commands(sub, (*path, name))


# The commands that write a file or folder (issue 36, item 7), and those that draw a progress bar.
WRITERS = {"generate", "assets preview", "show", "view", "export", "pattern make", "stats", "train", "eval",
           "infer", "capture import", "capture pattern", "capture record", "capture info",
           "capture fit-sensor", "capture compare"}
WITH_A_BAR = {"generate", "assets build", "train", "eval", "infer", "capture import", "capture record"}


def test_every_output_is_dash_o_or_dash_dash_out_and_every_bar_can_be_left_out():
    found = dict(commands(build_parser()))
    for name, parser in found.items():
        by_string = {s: a for a in parser._actions for s in a.option_strings}
        key = " ".join(name)
        if key in WRITERS:
            assert "-o" in by_string and by_string["-o"] is by_string["--out"], key
        else:
            assert "-o" not in by_string and "--out" not in by_string, key
        for old in ("--output", "--save"):  # earlier spellings live on as aliases of -o/--out only
            assert old not in by_string or by_string[old] is by_string["-o"], (key, old)
        assert ("--no-progress" in by_string) == (key in WITH_A_BAR), key
    assert WRITERS | WITH_A_BAR <= {" ".join(name) for name in found}


@pytest.mark.parametrize("new, old", [
    (["show", "d", "-o", "x.png"], ["show", "d", "--output", "x.png"]),
    (["stats", "d", "--out", "x.png"], ["stats", "d", "--output", "x.png"]),
    (["view", "d", "-o", "x.rrd"], ["view", "d", "--save", "x.rrd"]),
    (["pattern", "make", "-o", "p.png"], ["pattern", "make", "--output", "p.png"]),
    (["capture", "info", "--device", "opencv:0", "-o", "r.json"],
     ["capture", "info", "--device", "opencv:0", "--output", "r.json"]),
    (["assets", "preview", "--split", "train", "-o", "a.png"],
     ["assets", "preview", "--split", "train", "--output", "a.png"]),
    (["generate", "--config", "tiny", "--split", "train", "--scenes", "1", "-o", "d"],
     ["generate", "--config", "tiny", "--split", "train", "--scenes", "1", "--out", "d"]),
])
def test_the_earlier_spellings_are_still_accepted(new, old):
    assert vars(build_parser().parse_args(new)) == vars(build_parser().parse_args(old))


def test_export_takes_its_output_by_either_spelling_but_once(tmp_path, monkeypatch, capsys):
    """-o OUT, or OUT after DIR as before, also after other options (`export DIR --format webdataset
    OUT`, the README's old line): parsed as commands.cli.main parses (the data is missing here: status 1)."""
    from dotsim.command_options import take_positional_output

    monkeypatch.chdir(tmp_path)
    parser = build_parser()
    for argv in (["export", "d", "-o", "w"], ["export", "d", "w"],
                 ["export", "d", "--format", "webdataset", "w"], ["export", "-o", "w", "d", "--shards", "2"]):
        args, extras = parser.parse_known_args(argv)
        assert take_positional_output(args, extras, parser.error) == []
        assert (args.dataset, args.out) == ("d", "w")
        assert main(argv) == 1  # the command ran: the dataset is missing, one line
        assert "dotsim export: error: d: dataset directory does not exist" in capsys.readouterr().err
    for argv, message in ((["export", "d"], "export: the output is required: -o/--out OUT"),
                          (["export", "d", "w", "-o", "v"], "export: give the output once: -o v or w"),
                          (["export", "d", "w", "x"], "unrecognized arguments: x"),
                          (["show", "d", "x.png"], "unrecognized arguments: x.png")):
        with pytest.raises(SystemExit) as caught:
            main(argv)
        assert caught.value.code == 2 and message in capsys.readouterr().err, argv
    assert not any(tmp_path.iterdir())


def test_every_rig_option_takes_the_same_things():
    """No --rig is limited to presets (pattern's were): each takes a preset, a rig file or a config."""
    rigs = {" ".join(name): parser for name, parser in commands(build_parser())
            if any("--rig" in a.option_strings for a in parser._actions)}
    assert set(rigs) == {"generate", "pattern make", "pattern stats", "capture import", "capture pattern",
                         "capture record"}
    for name, parser in rigs.items():
        action = next(a for a in parser._actions if "--rig" in a.option_strings)
        assert action.choices is None and action.type is None, name
        assert "rig file" in action.help and ("config" in action.help or "as for import" in action.help), name
