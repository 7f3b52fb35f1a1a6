"""argparse types for the commands' numeric options: a value out of range is refused by the parser
itself, with the value and the allowed range in the message (`dotsim generate: error: argument
--scenes: '0': allowed: an integer >= 1`), before the command does anything.

>>> import argparse
>>> parser = argparse.ArgumentParser(prog="demo", exit_on_error=False)
>>> _ = parser.add_argument("--scenes", type=integer_at_least(1))
>>> parser.parse_args(["--scenes", "3"]).scenes
3
>>> parser.parse_args(["--scenes", "0"])
Traceback (most recent call last):
argparse.ArgumentError: argument --scenes: '0': allowed: an integer >= 1
"""

from __future__ import annotations

import argparse


def integer_at_least(low: int):
    """An argparse type: an integer >= low; anything else is refused naming the value and the range."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < low:
            raise argparse.ArgumentTypeError(f"{text!r}: allowed: an integer >= {low}")
        return value
    return parse
