"""The `dotsim` command: one subcommand per stage, each defined beside the stage it drives."""

import argparse
import importlib
import sys

from dotsim.command_options import take_positional_output
from dotsim.file_io import DiskFullError, WriteError
from dotsim.process_lifetime import Stopped, stop_signals
from dotsim.version import __version__

# command -> the module that defines it, in --help order. Each module defines add_parser(subparsers),
# adding its commands; the parser it adds sets `func(args) -> int` and may set `errors`, {error
# type: exit status}: the errors its command expects (bad input named in the message), reported as
# one line on stderr instead of a traceback.
COMMANDS = {
    "generate": "generator.cli",
    "assets": "assets_manifest.cli",
    "show": "commands.show",
    "view": "commands.view",
    "export": "commands.export",
    "pattern": "commands.pattern",
    "verify": "commands.dataset",
    "seal": "commands.dataset",
    "config": "commands.config",
    "rig": "commands.rig",
    "stats": "commands.stats",
    "train": "trainer.cli",
    "eval": "trainer.cli",
    "infer": "trainer.cli",
    "capture": "capture.cli",
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The `dotsim` parser with every command, or with only the module of `command` when it is one
    of COMMANDS: a run imports what its own command needs and no other stage (the trainer's torch
    takes longer to import than `dotsim generate` takes to start)."""
    parser = argparse.ArgumentParser(
        prog="dotsim",
        description="Synthetic structured-light training data (headless Blender/Cycles), "
        "and the GigaDepth network trained on it.",
    )
    parser.add_argument("--version", action="version", version=f"dotsim {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    modules = [COMMANDS[command]] if command in COMMANDS else COMMANDS.values()
    for name in dict.fromkeys(modules):
        importlib.import_module(name).add_parser(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    # the first word that is no option names the command (dotsim takes no option with a value)
    command = next((word for word in argv if not word.startswith("-")), None)
    parser = build_parser(command)
    # parse_args, but a command's output may also be one argument left over (export's earlier spelling)
    args, extras = parser.parse_known_args(argv)
    extras = take_positional_output(args, extras, parser.error)
    if extras:
        parser.error(f"unrecognized arguments: {' '.join(extras)}")
    # Any stage can run out of space or find its output folder unwritable: the message names the
    # file (and the space it needed), and the atomic writer left nothing half-written behind.
    errors = {DiskFullError: 1, WriteError: 1, **getattr(args, "errors", {})}
    try:
        # SIGTERM and SIGHUP stop a command as Ctrl-C does: its workers are stopped, never orphaned.
        with stop_signals():
            return int(args.func(args) or 0)
    except Stopped as stop:
        print(f"dotsim {args.command}: {stop}", file=sys.stderr)
        return 128 + stop.signum
    except tuple(errors) as error:
        print(f"dotsim {args.command}: error: {error}", file=sys.stderr)
        return next(status for kind, status in errors.items() if isinstance(error, kind))


if __name__ == "__main__":
    sys.exit(main())
