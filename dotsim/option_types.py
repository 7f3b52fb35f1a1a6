"""argparse types for the commands' numeric options: a value out of range is refused by the parser
itself, with the value and the allowed range in the message (`dotsim generate: error: argument
--scenes: '0': allowed: an integer >= 1`), before the command does anything. A config setting's
bounds serve as they are: `number(**bounds_of(Rig, "max_depth"))` (dotsim.config_schema).

>>> import argparse
>>> parser = argparse.ArgumentParser(prog="demo", exit_on_error=False)
>>> _ = parser.add_argument("--scenes", type=integer(1))
>>> _ = parser.add_argument("--scale", type=number(0.0, 1.0, low_open=True))
>>> parser.parse_args(["--scenes", "3", "--scale", "0.5"])
Namespace(scenes=3, scale=0.5)
>>> parser.parse_args(["--scenes", "0"])
Traceback (most recent call last):
argparse.ArgumentError: argument --scenes: '0': allowed: an integer >= 1
>>> parser.parse_args(["--scale", "1e400"])
Traceback (most recent call last):
argparse.ArgumentError: argument --scale: '1e400': allowed: a number > 0 and <= 1
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def _range(kind: str, low, high, low_open: bool = False, high_open: bool = False) -> str:
    """'an integer >= 1', 'a number > 0 and <= 1': what an option allows, in words."""
    bounds = [f"{sign} {value:g}" for sign, value in ((">" if low_open else ">=", low),
                                                      ("<" if high_open else "<=", high))
              if value is not None]
    return " ".join([kind, " and ".join(bounds)]).rstrip()


def _inside(value: float, low, high, low_open: bool, high_open: bool) -> bool:
    return (low is None or (value > low if low_open else value >= low)) and \
        (high is None or (value < high if high_open else value <= high))


def integer(low: int | None = None, high: int | None = None, low_open: bool = False,
            high_open: bool = False) -> Callable[[str], int]:
    """An argparse type: an integer within the bounds (None: unbounded; `low_open` / `high_open`
    leave the bound itself out, as dotsim.config_schema.setting's); anything else is refused naming
    the value and the range."""
    allowed = _range("an integer", low, high, low_open, high_open)

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or not _inside(value, low, high, low_open, high_open):
            raise argparse.ArgumentTypeError(f"{text!r}: allowed: {allowed}")
        return value
    return parse


def number(low: float | None = None, high: float | None = None, low_open: bool = False,
           high_open: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite number within the bounds (as integer's); anything else, inf and nan
    included, is refused naming the value and the range."""
    allowed = _range("a number", low, high, low_open, high_open)

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and _inside(value, low, high, low_open, high_open)):
            raise argparse.ArgumentTypeError(f"{text!r}: allowed: {allowed}")
        return value
    return parse
