"""The options every dotsim command spells alike (docs: README "Usage"): where its output goes, `-o/--out`,
and, where it draws a progress bar, `--no-progress`. A command's earlier spellings of its output option
(`--output`, `--save`, export's OUT after its input) stay accepted.

>>> import argparse
>>> parser = argparse.ArgumentParser(prog="show")
>>> add_output(parser, "image to write", metavar="FILE", old=("--output",))
>>> parser.parse_args(["-o", "a.png"]).out, parser.parse_args(["--output", "a.png"]).out
('a.png', 'a.png')
"""

from __future__ import annotations

import argparse


def add_output(parser: argparse.ArgumentParser, help: str, *, metavar: str = "OUT", required: bool = True,
               old: tuple[str, ...] = (), dest: str = "out", **kwargs) -> None:
    """`-o/--out` on a command's parser, with `old`, the command's earlier spellings of it, as aliases
    that stay accepted (the help names them as such); `dest` and other argparse keywords pass on."""
    if old:
        help += f" ({', '.join(old)}: the earlier spelling, still accepted)"
    parser.add_argument("-o", "--out", *old, dest=dest, metavar=metavar, required=required, help=help,
                        **kwargs)


def add_output_or_positional(parser: argparse.ArgumentParser, help: str, *, metavar: str = "OUT") -> None:
    """`-o/--out` (dest "out") for a command that took its output as one more argument after its input
    (`dotsim export DIR OUT`, `... DIR --format webdataset OUT`): that form stays accepted, anywhere
    among the options, which argparse's optional positionals cannot do; the program takes it from the
    arguments argparse leaves over (take_positional_output)."""
    parser.add_argument("-o", "--out", metavar=metavar, default=None,
                        help=f"{help} (required; {metavar} after the other arguments, the earlier spelling, "
                        "is still accepted)")
    parser.set_defaults(positional_output=metavar)


def take_positional_output(args: argparse.Namespace, extras: list[str], error) -> list[str]:
    """For a command of add_output_or_positional: args.out from -o/--out or from the one argument
    argparse left over (not an option); returns what is still left over. `error(message)` (argparse's
    parser.error: exit status 2) when the output is given twice, or not at all."""
    metavar = getattr(args, "positional_output", None)
    if metavar is None:
        return extras
    positional = [text for text in extras if not text.startswith("-")]
    if positional and args.out is not None:
        error(f"{args.command}: give the output once: -o {args.out} or {positional[0]}")
    if positional:
        args.out = positional[0]
        extras = [text for text in extras if text is not positional[0]]
    if args.out is None:
        error(f"{args.command}: the output is required: -o/--out {metavar}")
    return extras


def add_no_progress(parser: argparse.ArgumentParser) -> None:
    """`--no-progress` (dest "no_progress"): leave out the progress bar (logs, batch jobs)."""
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
