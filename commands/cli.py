"""The `dotsim` command: one subcommand per stage, each defined beside the stage it drives."""

import argparse
import importlib
import sys

from dotsim.file_io import DiskFullError, WriteError
from dotsim.process_lifetime import Stopped, stop_signals
from dotsim.version import __version__

# Each module defines add_parser(subparsers); the parser it adds sets `func(args) -> int` and may
# set `errors`, {error type: exit status}: the errors its command expects (bad input named in the
# message), reported as one line on stderr instead of a traceback.
SUBCOMMAND_MODULES = [
    "generator.cli",
    "assets_manifest.cli",
    "commands.show",
    "commands.view",
    "commands.export",
    "commands.pattern",
    "commands.dataset",
    "commands.config",
    "commands.stats",
    "trainer.cli",
    "capture.cli",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dotsim",
        description="Synthetic structured-light training data (headless Blender/Cycles), "
        "and the GigaDepth network trained on it.",
    )
    parser.add_argument("--version", action="version", version=f"dotsim {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in SUBCOMMAND_MODULES:
        importlib.import_module(name).add_parser(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
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
