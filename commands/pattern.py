"""`dotsim pattern`: make a procedural dot pattern for a rig's projector, or print a pattern's statistics."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from dotsim.command_options import add_output
from dotsim.config_schema import bounds_of
from dotsim.file_io import atomic_write_json
from dotsim.option_types import integer, number
from dotsim.patterns import (
    DEFAULT_DENSITY,
    PatternError,
    generate_dot_pattern,
    load_pattern,
    pattern_statistics,
)
from dotsim.rig.options import rig_from_options
from dotsim.rig.presets import DEFAULT_PRESET, PRESETS
from generator.config import PatternConfig


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "pattern",
        help="make a dot pattern for a projector, or print a pattern's statistics",
        description="Procedural projector dot patterns (Poisson-disc dots drawn as Gaussians) and "
        "statistics of any pattern image (8/16-bit PNG or EXR).",
    )
    actions = parser.add_subparsers(dest="pattern_command", metavar="ACTION", required=True)

    make = actions.add_parser(
        "make",
        help="write a procedural dot pattern (16-bit PNG) at a rig's projector resolution",
        description="Write a reproducible Poisson-disc dot pattern as a 16-bit grey PNG at the "
        "projector resolution of a rig preset, plus OUTPUT.json with its parameters and sha256.",
    )
    make.add_argument("--rig", default=None, metavar="PRESET_OR_FILE",
                      help="the rig whose projector resolution the pattern gets, as every --rig takes it: a "
                      f"preset ({', '.join(PRESETS)}; default {DEFAULT_PRESET}), a rig file or a generator "
                      "config (.toml; docs/GEOMETRY.md \"Rig files\")")
    make.add_argument("--scale", type=number(0.0, 1.0, low_open=True), default=1.0,
                      help="scale the rig first (as Rig.scaled, e.g. 0.25 for tiny test renders; default 1)")
    make.add_argument("--seed", type=integer(0), default=0, help="random seed (default 0)")
    amount = make.add_mutually_exclusive_group()
    amount.add_argument("--density", type=number(**bounds_of(PatternConfig, "density")),
                        help=f"dots per pattern pixel (default {DEFAULT_DENSITY})")
    amount.add_argument("--n-dots", type=integer(1), help="number of dots (instead of --density)")
    make.add_argument("--min-spacing", type=number(**bounds_of(PatternConfig, "min_spacing")), default=3.0,
                      help="least distance between dot centres in pattern px (default 3)")
    make.add_argument("--sigma", type=number(**bounds_of(PatternConfig, "dot_sigma")), default=0.8,
                      help="Gaussian dot standard deviation in pattern px (default 0.8)")
    add_output(make, "output .png path", metavar="PNG", old=("--output",), dest="output", type=Path)
    make.set_defaults(func=_make)

    stats = actions.add_parser(
        "stats",
        help="print dot count, density, spacing and row-window uniqueness of a pattern image",
        description="Print statistics of a pattern image: detected dot count, density (dots per "
        "pixel), mean/min nearest-neighbour spacing, and the share of windows along rows whose best "
        "NCC against every other window within the search range is below the threshold.",
    )
    stats.add_argument("pattern", type=Path, help="pattern image (8/16-bit PNG or EXR)")
    stats.add_argument("--window", type=integer(1), default=9, help="window side in px (default 9)")
    stats.add_argument("--search", type=integer(1), default=128,
                       help="horizontal search range in px (default 128)")
    stats.add_argument("--rig", default=None, metavar="PRESET_OR_FILE",
                       help="read --window and --search as camera px of this rig (a preset, a rig file or a "
                       "generator config, as for `pattern make`; converted with its projector/camera focal "
                       "ratio); without it they are pattern px")
    stats.add_argument("--ncc-threshold", type=number(-1.0, 1.0), default=0.9,
                       help="a window is unique when its best NCC is below this (default 0.9)")
    stats.add_argument("--json", action="store_true", help="print the statistics as JSON")
    stats.set_defaults(func=_stats)


def _make(args: argparse.Namespace) -> int:
    try:
        rig = rig_from_options(args.rig).rig
        if args.scale != 1.0:
            rig = rig.scaled(args.scale)
        start = time.perf_counter()
        pattern = generate_dot_pattern(rig.projector.width, rig.projector.height, n_dots=args.n_dots,
                                       density=args.density, min_spacing=args.min_spacing,
                                       dot_sigma=args.sigma, seed=args.seed)
        path = pattern.save_png(args.output)
    except (PatternError, ValueError) as error:
        print(f"dotsim pattern make: error: {error}", file=sys.stderr)
        return 2
    record = {"source": pattern.source, "sha256": pattern.sha256, "width": pattern.width,
              "height": pattern.height, "rig": rig.name, "scale": args.scale, "params": pattern.params}
    atomic_write_json(path.with_suffix(".json"), record)
    print(f"wrote {path} ({pattern.width}x{pattern.height}, {len(pattern.centres)} dots, seed {args.seed}, "
          f"sha256 {pattern.sha256[:12]}) in {time.perf_counter() - start:.1f} s")
    return 0


def _stats(args: argparse.Namespace) -> int:
    window, search = args.window, args.search
    try:
        if args.rig:
            rig = rig_from_options(args.rig).rig
            ratio = rig.projector.fx / rig.camera.fx
            window = round(window * ratio) | 1  # keep the window odd so it has a centre pixel
            search = round(search * ratio)
        stats = pattern_statistics(load_pattern(args.pattern), window=window, search=search,
                                   ncc_threshold=args.ncc_threshold)
    except (PatternError, ValueError) as error:
        print(f"dotsim pattern stats: error: {error}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(stats, indent=2))
        return 0
    print(f"{args.pattern}: {stats['width']}x{stats['height']} px, sha256 {stats['sha256'][:12]}")
    print(f"  dots: {stats['dot_count']}  density: {stats['density']:.5f} dots/px  "
          f"spacing: mean {stats['mean_spacing']:.2f} px, min {stats['min_spacing']:.2f} px")
    print(f"  row windows {window}x{window} px, search +-{search} px: "
          f"{100 * stats['row_window_uniqueness']:.1f}% unique (best NCC < {args.ncc_threshold}), "
          f"{100 * stats['flat_window_share']:.1f}% empty, median best NCC {stats['median_best_ncc']:.3f} "
          f"({stats['windows_tested']} windows)")
    return 0
