"""`dotsim generate`: render a resumable dataset of four-frame structured-light scenes."""

from __future__ import annotations

import argparse
import sys

DESCRIPTION = """\
Render scenes START .. START+N-1 of a split into DIR with headless Blender (Cycles): each scene is
a room with hundreds of textured objects seen from four nearby rig poses; every frame stores the
sensor-model IR image, the ambient and flood passes, depth, visibility and edge masks, and the
ground-truth projector column and disparity (docs/FORMAT.md). Scene k depends only on (config, k,
--seed), never on the worker that renders it.

Everything is checked before anything is written: a bad config key, type or range, a missing
pattern or asset file, an unwritable DIR or a DIR holding a dataset made with other settings
stops the run with a message naming the file, key and value. Rerunning the same command resumes:
complete scenes are skipped, half-written and damaged ones (a frame deleted) are redone, and the
dataset is sealed again (shard.json, index.json; `dotsim verify DIR` checks every checksum). A
failing scene is logged in DIR/logs/ and the run goes on; the exit status is 1 when any scene
failed or the disk is full, 2 on a config error.
"""

EPILOG = """\
examples:
  dotsim generate --config configs/default.toml --out out/dataset --split train --scenes 4
  dotsim generate --config configs/structure_core.toml --out data/test --split test --scenes 200 \\
      --workers 2 --seed 1
  dotsim generate --config configs/tiny.toml --out /tmp/tiny --split train --scenes 2 \\
      --blender /opt/blender/blender        # Blender executable instead of the bpy module
Config keys: docs/CONFIG.md.
"""


def _integer_at_least(low: int):
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


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the `generate` subcommand to the dotsim CLI."""
    parser = subparsers.add_parser(
        "generate", help="render a dataset of structured-light scenes with Blender (resumable)",
        description=DESCRIPTION, epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", required=True, metavar="TOML",
                        help="generator config, e.g. configs/default.toml (keys: docs/CONFIG.md)")
    parser.add_argument("--out", required=True, metavar="DIR", help="dataset directory (created; resumed)")
    parser.add_argument("--split", required=True, choices=("train", "test"),
                        help="asset split and clutter density to draw from")
    parser.add_argument("--scenes", required=True, type=_integer_at_least(1), metavar="N",
                        help="number of scenes")
    parser.add_argument("--start", type=_integer_at_least(0), default=0, metavar="K",
                        help="index of the first scene (default 0); scene indices are global, so "
                             "ranges rendered on several machines merge into one dataset")
    parser.add_argument("--workers", type=_integer_at_least(1), default=1, metavar="W",
                        help="render processes on this machine (default 1); each holds one Blender "
                             "scene for all its scenes. Set [render] threads so W x threads fits the cores")
    parser.add_argument("--seed", type=_integer_at_least(0), default=0, metavar="S",
                        help="base seed (default 0): scene k uses SeedSequence((S, k))")
    parser.add_argument("--blender", metavar="EXE", default=None,
                        help="render with this Blender executable (`EXE --background --python "
                             "generator/blender/run_in_blender.py`) instead of the bpy module")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--no-seal", action="store_true",
                        help="do not seal at the end (tasks of a cluster run that writes one dataset "
                             "from many machines; run `dotsim seal DIR` once they are done)")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    from dotsim.dataset import FormatError
    from generator.config import ConfigError, load_config
    from generator.pipeline import generate, main_summary

    try:
        config = load_config(args.config)
        summary = generate(config, args.out, args.split, args.scenes, start=args.start,
                           workers=args.workers, seed=args.seed, blender=args.blender,
                           progress=not args.no_progress, seal=not args.no_seal)
    except ConfigError as exc:
        print(f"dotsim generate: error: {exc}", file=sys.stderr)
        return 2
    except FormatError as exc:  # the dataset on disk: e.g. a damaged scene outside this run's range
        print(f"dotsim generate: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("dotsim generate: interrupted; complete scenes are kept, rerun the same command to resume",
              file=sys.stderr)
        return 130
    return main_summary(summary)
