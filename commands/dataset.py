"""`dotsim verify DIR [--repair]` and `dotsim seal DIR`: check, mend and seal a dataset."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dotsim.dataset import FormatError, repair_dataset, seal_dataset, verify_dataset
from dotsim.dataset.lock import writer_lock
from dotsim.dataset.verify import format_indices

VERIFY_DESCRIPTION = """\
Check a dataset end to end, as after copying it between machines or after a crash: every frame
against the sha256 its scene.json recorded at write time, every scene.json against its entry in
shard.json, every shard.json and dataset-level file against index.json, index.json's counts and
versions against the shard.json files, and the seal against the scene folders on disk. Only
checksums are trusted. Prints one line per problem, naming the file; exit status 1 when any.

With --repair: removes what differs from its seal and seals again from what is intact: damaged
scenes (a frame missing or corrupt, scene.json missing, invalid or changed after it was sealed),
shard.json files index.json does not vouch for (derived again from the scenes' own checksums)
and the leftovers of crashed writers, so that rerunning the same `dotsim generate` command
renders exactly the removed scenes. It never hashes a changed file into the seal. A dataset-level
file that no longer matches index.json, or one index.json does not list, stops the seal (restore
or remove it; pattern.png and generate.json may be deleted instead, `dotsim generate` writes them
again from its config): the seal never vouches for a file verify flagged.
"""

SEAL_DESCRIPTION = """\
Write shard.json for every shard and index.json for the dataset (docs/FORMAT.md), from the
complete scenes on disk. Incremental: shards whose shard.json still lists exactly their scenes
are kept without reading frames, so it is cheap to run after every task of a cluster run and
right whatever order the tasks finished in. `dotsim generate` seals at the end of every run.
"""


def add_parser(subparsers) -> None:
    """Add the `verify` and `seal` subcommands to the dotsim CLI."""
    verify = subparsers.add_parser(
        "verify", help="check every file of a dataset against its checksums; --repair mends it",
        description=VERIFY_DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    verify.add_argument("dataset", metavar="DIR", help="dataset directory")
    verify.add_argument("--repair", action="store_true",
                        help="remove damaged scenes and leftovers and seal again, so the next "
                             "`dotsim generate` redoes exactly the removed scenes")
    # no dataset there, dataset.json unreadable, a scene damaged before its first seal: exit 2
    verify.set_defaults(func=_verify, errors={FormatError: 2})
    seal = subparsers.add_parser(
        "seal", help="write shard.json files and index.json from the scenes on disk (incremental)",
        description=SEAL_DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    seal.add_argument("dataset", metavar="DIR", help="dataset directory")
    seal.set_defaults(func=_seal, errors={FormatError: 2})


def _verify(args: argparse.Namespace) -> int:
    if args.repair and Path(args.dataset).is_dir():
        # repair removes scenes: no generate may be writing them meanwhile
        with writer_lock(args.dataset, "dotsim verify --repair"):
            return _verify_and_repair(args)
    return _verify_and_repair(args)


def _verify_and_repair(args: argparse.Namespace) -> int:
    report = verify_dataset(args.dataset)
    for problem in report.problems:
        print(problem.line())
    if report.absent:
        print(f"note: no scene folder for scene indices {format_indices(report.absent)} (never rendered, "
              f"or removed); `dotsim generate` with a range covering them renders them")
    print(report.line(), file=sys.stderr if report.problems else sys.stdout)
    if not report.problems:
        return 0
    if not args.repair:
        print(f"run `dotsim verify {args.dataset} --repair`, then the same `dotsim generate` command",
              file=sys.stderr)
        return 1
    repair = repair_dataset(report)
    redo = report.damaged_scenes
    shard_files = f", {len(repair.removed_shard_files)} shard.json" if repair.removed_shard_files else ""
    print(f"repair: removed {len(repair.removed_scenes)} damaged scene(s){shard_files} and "
          f"{len(repair.removed_leftovers)} leftover(s)")
    if repair.seal is None:
        print("repair: not sealed, a dataset-level file no longer matches index.json or is not listed in it "
              "(above); restore or remove it and run `dotsim verify` again", file=sys.stderr)
        return 1
    print(f"repair: {repair.seal.line()}")
    if redo:
        print(f"rerun the same `dotsim generate` command to render scenes {format_indices(redo)} again")
    return 0


def _seal(args: argparse.Namespace) -> int:
    result = seal_dataset(args.dataset)
    print(f"{args.dataset}: {result.line()}")
    return 0

