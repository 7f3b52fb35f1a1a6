"""Parameters of procedural families: validation against a family's defaults, and per-seed sampling.

A manifest gives each parameter either a fixed value or a range to draw from per seed:
  - a number, string or bool                -> used as is
  - [lo, hi] with two numbers               -> uniform draw in [lo, hi] (integers if both are ints,
                                               inclusive of hi)
  - a list of strings                       -> one of them, uniformly (a family lists the
                                               strings it knows in its defaults)
"""

import json
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from dotsim.file_io import sha256_bytes


@dataclass(frozen=True)
class Family:
    """A procedural family: `make(params, rng)` builds one asset from concrete parameters; `defaults`
    lists every parameter it takes, with the value or range used when a manifest does not set it."""

    make: Callable
    defaults: dict


def canonical_json(value) -> str:
    """JSON with sorted keys and no whitespace: the one spelling that is hashed everywhere."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"))


def spec_seed(spec: dict) -> int:
    """A 64-bit seed derived from a source spec, so any change of family, parameter or seed gives an
    independent random stream (two entries differing only in a parameter do not share draws)."""
    return int(sha256_bytes(canonical_json(spec).encode())[:16], 16)


def _is_number(x) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool)


def check_params(given: dict, defaults: dict, where: str) -> list[str]:
    """Problems with a manifest's `params` for a family whose parameters and defaults are `defaults`;
    each problem names `where` (file and entry), the parameter and what is allowed. A parameter whose
    default is a list of strings takes any non-empty subset of those strings (or one of them)."""
    problems = []
    for key, value in given.items():
        if key not in defaults:
            problems.append(f"{where}: unknown parameter {key!r}; allowed: {', '.join(sorted(defaults))}")
            continue
        default = defaults[key]
        values = value if isinstance(value, list) else [value]
        if isinstance(default, list) and all(isinstance(v, str) for v in default):
            if not values or not all(isinstance(v, str) and v in default for v in values):
                problems.append(
                    f"{where}: parameter {key!r} = {value!r}; allowed: one or a list of {default}"
                )
        elif isinstance(default, str | bool):
            if type(value) is not type(default):
                problems.append(f"{where}: parameter {key!r} = {value!r} must be a {type(default).__name__}")
        elif not all(_is_number(v) for v in values) or (isinstance(value, list) and len(value) != 2):
            problems.append(f"{where}: parameter {key!r} = {value!r} must be a number or [lo, hi] numbers")
        elif isinstance(value, list) and value[0] > value[1]:
            problems.append(f"{where}: parameter {key!r} range {value} has lo > hi")
    return problems


def sample_params(given: dict, defaults: dict, rng: np.random.Generator) -> dict:
    """Concrete values for one seed: defaults overridden by `given`, ranges drawn from `rng` in the
    sorted order of parameter names (so adding a parameter never reorders earlier draws' meaning)."""
    merged = {**defaults, **given}
    out = {}
    for key in sorted(merged):
        value = merged[key]
        if isinstance(value, list) and len(value) == 2 and all(_is_number(v) for v in value):
            lo, hi = value
            if isinstance(lo, int) and isinstance(hi, int):
                out[key] = int(rng.integers(lo, hi + 1))
            else:
                out[key] = float(rng.uniform(lo, hi))
        elif isinstance(value, list):
            out[key] = value[int(rng.integers(len(value)))]
        else:
            out[key] = value
    return out
