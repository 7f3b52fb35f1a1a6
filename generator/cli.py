"""`dotsim generate`: render a resumable dataset of four-frame structured-light scenes."""

from __future__ import annotations

import argparse
import importlib
import signal
import sys
from dataclasses import replace
from types import ModuleType
from typing import TYPE_CHECKING

from dotsim.command_options import add_no_progress, add_output
from dotsim.dataset import FormatError
from dotsim.option_types import integer
from generator.config import ConfigError
from generator.scene_spec import SPLITS

if TYPE_CHECKING:  # run_request loads the pattern code (scipy); a parser needs none of it
    from generator.run_request import Executor

DESCRIPTION = """\
Render scenes START .. START+N-1 of a split into DIR with headless Blender (Cycles): each scene is
a room with hundreds of textured objects seen from four nearby rig poses; every frame stores the
sensor-model IR image, the ambient and flood passes, depth, visibility and edge masks, and the
ground-truth projector column and disparity (docs/FORMAT.md). Scene k depends only on (config, k,
--seed), never on the worker that renders it.

Everything is checked before anything is written: a bad config key, type or range, a missing pattern
or asset file, an unwritable DIR, a DIR holding anything but a dataset of rendered scenes
(dotsim.output_folder) or one made with other settings stops the run with a message naming the file,
key and value. Rerunning the same command resumes: complete scenes are skipped, half-written and
damaged ones (a frame deleted) are redone, and the dataset is sealed again (shard.json, index.json;
`dotsim verify DIR` checks every checksum). A failing scene is logged in DIR/logs/ and the run goes
on; the exit status is 1 when any scene failed or the disk is full, 2 on a config error. Every input
a render reads (textures, meshes, pattern) is checked against its recorded sha256 first. One writer
per DIR: a second run into it is refused, naming the first one's pid (--no-seal range tasks take no
lock). The render workers never outlive the run: Ctrl-C, SIGTERM and SIGHUP stop them (exit status
128 + the signal), and a run killed outright (kill -9) takes them with it.

Past one machine (docs/SCALE.md): --ray renders on a Ray cluster (one task per two scenes, retried
when a node dies); --slurm submits a Slurm job array (one task per range of scenes, each the same
resumable command with --no-seal) and a job that seals the dataset when the array has ended
(--seal-only). DIR must be on a filesystem every node mounts at the same path; this is checked
before anything is written (Ray) or before a task writes anything (Slurm).
"""

EPILOG = """\
examples:
  dotsim generate --config default --out out/dataset --split train --scenes 4
  dotsim generate --config structure_core --out data/test --split test --scenes 200 \\
      --workers 2 --seed 1
  dotsim generate --config table2 --out data/table2/test_seen --split test --scenes 20 \\
      --seed 1 --test-assets train          # test scenes of the training meshes (like-for-like)
  dotsim generate --config tiny --out /tmp/tiny --split train --scenes 2 \\
      --blender /opt/blender/blender        # Blender executable instead of the bpy module
  dotsim generate --config structure_core --out /shared/train --split train \\
      --scenes 15000 --ray auto             # on the Ray cluster this machine belongs to
  dotsim generate --config structure_core --out /shared/train --split train \\
      --scenes 15000 --slurm --slurm-partition cpu --slurm-cpus 8 --slurm-dry-run
Config keys: docs/CONFIG.md.
"""


# The engine modules `dotsim generate` offers besides the local pool, in --help order (each defines
# add_options and from_args: generator/run_request.py).
ENGINES = ("generator.engines.ray_cluster", "generator.engines.slurm")


def engine_modules() -> list[ModuleType]:
    """The modules of ENGINES."""
    return [importlib.import_module(name) for name in ENGINES]


def executor_from_args(args: argparse.Namespace) -> Executor:
    """The executor the parsed `dotsim generate` options ask for: an engine of ENGINES, or the
    local pool of --workers processes. ConfigError when they ask for more than one engine."""
    from generator.engines.local_pool import LocalExecutor

    chosen = [executor for executor in (module.from_args(args) for module in engine_modules()) if executor]
    if len(chosen) > 1:
        raise ConfigError(f"{' and '.join(executor.option for executor in chosen)}: choose one")
    return chosen[0] if chosen else LocalExecutor(args.workers or 1)


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the `generate` subcommand to the dotsim CLI."""
    parser = subparsers.add_parser(
        "generate", help="render a dataset of structured-light scenes with Blender (resumable)",
        description=DESCRIPTION, epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", required=True, metavar="NAME_OR_TOML",
                        help="generator config: a built-in one's name (default, structure_core, kinect, "
                             "tiny, bench_accuracy; `dotsim config show NAME` prints it), a TOML file "
                             "(keys: docs/CONFIG.md) or a config saved as JSON "
                             "(generator.config.config_json: what a --slurm run's tasks read)")
    parser.add_argument("--rig", metavar="PRESET_OR_FILE", default=None,
                        help="the rig instead of the config's [rig] preset / file: a preset (structure_core, "
                             "kinect_v1, realsense_d415), a rig file (dotsim rig JSON, OpenCV, ROS "
                             "camera_info or Kalibr calibration; docs/GEOMETRY.md \"Rig files\"; a file of a "
                             "camera alone is its camera_file, with the preset's projector, and says so) or "
                             "a generator config (.toml: its [rig]); the config's other [rig] keys (scale, "
                             "...) still apply")
    parser.add_argument("--camera-file", metavar="FILE", default=None,
                        help="the IR camera from this calibration file (OpenCV's calibration sample, ROS "
                             "camera_info, Kalibr, or camera 1 of any rig file) instead of the rig's, as "
                             "[rig] camera_file; the projector and its pose stay the rig's")
    add_output(parser, "dataset directory (created; resumed)", metavar="DIR")
    parser.add_argument("--split", required=True, choices=SPLITS,
                        help="scene split, and the asset split and clutter density its scenes draw from "
                             "(test scenes: see --test-assets)")
    parser.add_argument("--test-assets", choices=("test", "train"), default=None,
                        help="[assets] test_assets: the test split's scenes draw the test assets (disjoint "
                             "from training) or the training ones (new scenes of seen meshes, as "
                             "DepthInSpace's test scenes; give another --seed than the training data's)")
    parser.add_argument("--scenes", required=True, type=integer(1), metavar="N",
                        help="number of scenes")
    parser.add_argument("--start", type=integer(0), default=0, metavar="K",
                        help="index of the first scene (default 0); scene indices are global, so "
                             "ranges rendered on several machines merge into one dataset")
    parser.add_argument("--workers", type=integer(1), default=None, metavar="W",
                        help="render processes on this machine (default 1); each holds one Blender "
                             "scene for all its scenes. Set [render] threads so W x threads fits the cores. "
                             "With --ray: at most W tasks at once (--ray local: a cluster of W x threads "
                             "CPUs; default: the whole cluster)")
    parser.add_argument("--seed", type=integer(0), default=0, metavar="S",
                        help="base seed (default 0): scene k uses SeedSequence((S, k))")
    parser.add_argument("--blender", metavar="EXE", default=None,
                        help="render with this Blender executable (`EXE --background --python "
                             "generator/blender/run_in_blender.py`) instead of the bpy module")
    add_no_progress(parser)
    seal = parser.add_mutually_exclusive_group()
    seal.add_argument("--no-seal", action="store_true",
                      help="seal only the shards wholly inside this range (no index.json), and remove only "
                           "this range's half-written scenes: for one of several runs writing into DIR at "
                           "once (each Slurm array task runs it); seal with --seal-only or `dotsim seal "
                           "DIR` once they are done")
    seal.add_argument("--seal-only", action="store_true",
                      help="render nothing: remove half-written scenes (no writer may be running), list the "
                           "scenes of the range still missing, and seal DIR (the Slurm sealing job)")
    cluster = parser.add_argument_group("clusters (docs/SCALE.md)")
    for engine in engine_modules():  # each engine module adds its own options
        engine.add_options(cluster)
    # A bad config or argument exits 2; a dataset on disk that does not fit (e.g. a damaged scene
    # outside this run's range) exits 1.
    parser.set_defaults(func=run, errors={ConfigError: 2, FormatError: 1})
    return parser


def _run(args: argparse.Namespace) -> int:
    from dotsim.rig.options import with_rig_options
    from dotsim.rig.report import summary_line
    from generator import driver
    from generator.config import load_config
    from generator.engines.steps import seal_run
    from generator.run_request import RunRequest

    executor = executor_from_args(args)
    config = load_config(args.config)
    if args.rig or args.camera_file:
        rig, _ = with_rig_options(config.rig, config.source, args.rig, args.camera_file)
        config = replace(config, rig=rig)
    if args.test_assets:
        config = replace(config, assets=replace(config.assets, test_assets=args.test_assets))
    request = RunRequest(config, args.out, args.split, args.scenes, args.start, args.seed, args.blender,
                         executor, progress=not args.no_progress, seal=not args.no_seal)
    print(summary_line(request.rig), flush=True)  # the rig that renders (`dotsim rig show` lists it)
    notes = (*request.rig.notes, request.rig.rectification_note(f"{config.source}: [rig]"))
    for note in filter(None, notes):
        print(note, file=sys.stderr)
    if args.seal_only:
        summary = seal_run(request)
        missing = summary.failed
        text = (f"{'not sealed' if summary.unsealed else 'sealed'} {summary.out}: {summary.skipped} of "
                f"{args.scenes} scenes complete")
        if missing:
            text += (f"; missing {missing[:10]}{' ...' if len(missing) > 10 else ''}: rerun the same command "
                     "without --seal-only (or resubmit) to render them")
        if summary.unsealed:
            text += f"; {summary.unsealed}"
        print(text, file=sys.stderr if missing or summary.unsealed else sys.stdout)
        return 1 if missing or summary.unsealed else 0
    try:
        return driver.main_summary(driver.run(request))
    finally:
        executor.close()


def run(args: argparse.Namespace) -> int:
    try:
        return _run(args)
    except KeyboardInterrupt as stop:  # Ctrl-C, or SIGTERM / SIGHUP (dotsim.process_lifetime.Stopped)
        signum = getattr(stop, "signum", signal.SIGINT)
        what = str(stop) if signum != signal.SIGINT else "interrupted"
        print(f"dotsim generate: {what}; workers stopped, complete scenes are kept, rerun the same "
              "command to resume", file=sys.stderr)
        return 128 + signum
