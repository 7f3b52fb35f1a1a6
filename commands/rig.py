"""`dotsim rig show CONFIG|FILE`: the rig a config renders, or a rig file, preset or calibration describes,
resolved as the commands resolve it, listed part by part with where each part came from."""

from __future__ import annotations

import argparse

from dotsim.config_schema import ConfigError
from dotsim.configs import builtin_names
from dotsim.rig.config import read_rig_config
from dotsim.rig.files import CalibratedRig
from dotsim.rig.options import rig_from_options, with_rig_options
from dotsim.rig.presets import PRESETS
from dotsim.rig.report import report_lines, summary_line


def is_generator_config(target: str) -> bool:
    """Whether `dotsim rig show TARGET` names a generator config (a built-in one's name, a .toml file) rather
    than a rig (a preset, a rig file)."""
    return target in builtin_names("generator") or target.lower().endswith(".toml")


def resolved(target: str, camera_file: str | None = None) -> tuple[CalibratedRig, str]:
    """The rig TARGET names (with --camera-file's camera) and a line saying how it was resolved: a
    generator config's as `dotsim generate --config TARGET` renders it (its [rig] scale included; only
    its [rig] table is read, so its asset cache need not exist), else as --rig of `dotsim capture` and
    `dotsim pattern` takes it (dotsim.rig.options.rig_from_options). ConfigError naming the file and the
    key."""
    if is_generator_config(target):
        settings, source = read_rig_config(target)
        settings, calibrated = with_rig_options(settings, source, camera_file=camera_file)
        return calibrated, (f"as `dotsim generate --config {target}` renders it ([rig] of {source}, scale "
                            f"{settings.scale:g})")
    return (rig_from_options(target, camera_file, option="rig show"),
            f"as --rig {target} gives it (capture, pattern)")


def run(args: argparse.Namespace) -> int:
    calibrated, how = resolved(args.target, args.camera_file)
    print(f"{summary_line(calibrated)}\n  {how}")
    print("\n".join(report_lines(calibrated)))
    return 0


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "rig", help="print a resolved rig: intrinsics, fields of view, baseline, pose, sources",
        description="Look at rigs: `show` prints the one-line summary `dotsim generate` prints when it "
        "starts, then the camera and projector (size, focal lengths, principal point, fields of view), the "
        "lens real frames are rectified from, the projector's pose and the baseline, the second camera, the "
        "max depth, where each of these came from (a preset, a file, a config key) and the notes of "
        "reading them (docs/GEOMETRY.md \"Seeing the rig\").")
    actions = parser.add_subparsers(dest="rig_command", metavar="ACTION", required=True)
    show = actions.add_parser(
        "show", help="the rig a generator config renders, or that a preset or rig file gives",
        description="TARGET: a generator config (a built-in one's name or a .toml file: its [rig] as `dotsim "
        "generate` renders it, scale included), a preset, or a rig file (a whole rig, or a camera alone "
        "with the default preset's projector: as --rig of `dotsim capture` and `dotsim pattern` takes it).")
    show.add_argument("target", metavar="CONFIG_OR_FILE",
                      help=f"a generator config ({', '.join(builtin_names('generator'))} or a .toml file), a "
                      f"preset ({', '.join(PRESETS)}) or a rig file (.json, .yaml, .yml, .xml)")
    show.add_argument("--camera-file", metavar="FILE", default=None,
                      help="with the IR camera of this calibration file instead, as generate's --camera-file")
    show.set_defaults(func=run)
    parser.set_defaults(errors={ConfigError: 2})
