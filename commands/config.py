"""`dotsim config`: list the built-in configs and print one to start a config of your own from."""

from __future__ import annotations

import argparse
import sys

from dotsim.config_schema import ConfigError
from dotsim.configs import builtin_names, builtin_path


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "config", help="list the built-in configs, or print one",
        description="The configs shipped inside dotsim: generator configs (--config of `dotsim generate`) "
        "and training configs (--config of `dotsim train`), usable by name. `show NAME > my.toml` gives a "
        "file to edit; its relative paths (cache_dir) are then relative to that file's folder.")
    actions = parser.add_subparsers(dest="config_command", metavar="ACTION", required=True)
    actions.add_parser("list", help="the built-in configs' names").set_defaults(func=_list)
    show = actions.add_parser("show", help="print a built-in config (TOML)")
    show.add_argument("name", metavar="NAME", help=f"one of: {', '.join(builtin_names())}")
    show.set_defaults(func=_show)
    parser.set_defaults(errors={ConfigError: 2})


def _list(args: argparse.Namespace) -> int:
    print("\n".join(builtin_names()))
    return 0


def _show(args: argparse.Namespace) -> int:
    path = builtin_path(args.name)
    if path is None:
        raise ConfigError(f"config {args.name!r}: no built-in config of that name; allowed: "
                          f"{', '.join(builtin_names())}")
    sys.stdout.write(path.read_text())
    return 0
