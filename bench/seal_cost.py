"""Benchmark: the cost of sealing (dotsim.dataset.seal_dataset), per scene, with and without
unchanged shards, against verifying every file (dotsim.dataset.verify_dataset).

    python -m bench.seal_cost --scenes 2000 --scenes-per-shard 100

Builds a dataset of --scenes copies of one rendered scene (its scene.json and frames; each copy's
scene.json carries its own scene_index), then times: the first seal (every scene's frames
hashed), a reseal with nothing changed (every shard kept: a listing and the scene.json files),
a reseal after one more shard of scenes was added, and a full verify. Frames are the tiny test
frames, so the frame-hashing rows scale with frame size; sha256 throughput is printed so that
full-resolution frames (7.9 MB each, docs/FORMAT.md) can be estimated.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

from dotsim import dataset
from dotsim.dataset.layout import record_layout
from dotsim.file_io import json_bytes

REPO = Path(__file__).resolve().parents[1]


def source_scene(work: Path) -> Path:
    """One scene rendered with dotsim/configs/tiny.toml (bpy, about 2 s)."""
    from generator.config import load_config
    from generator.driver import generate

    generate(load_config("tiny"), work / "source", "train", 1, progress=False)
    return dataset.scene_dir(work / "source", 0, 2)


def add_scenes(root: Path, source: Path, indices: range, scenes_per_shard: int) -> None:
    meta = json.loads((source / dataset.SCENE_FILE).read_bytes())
    for index in indices:
        target = dataset.scene_dir(root, index, scenes_per_shard)
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copytree(source, target)
        (target / dataset.SCENE_FILE).write_bytes(json_bytes({**meta, "scene_index": index}))


def timed(function, *args):
    start = time.perf_counter()
    result = function(*args)
    return result, time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=int, default=2000)
    parser.add_argument("--scenes-per-shard", type=int, default=100)
    parser.add_argument("--work", type=Path, default=None,
                        help="folder for the dataset (default: a temp dir)")
    args = parser.parse_args(argv)
    work = args.work or Path(tempfile.mkdtemp(prefix="dotsim-seal-cost-"))
    spp, n = args.scenes_per_shard, args.scenes
    source = source_scene(work)
    root = work / "dataset"
    shutil.rmtree(root, ignore_errors=True)
    root.mkdir(parents=True)
    record_layout(root, spp)
    add_scenes(root, source, range(n), spp)
    frame_bytes = sum(p.stat().st_size for p in source.glob("frame_*.exr"))
    scene_json = (source / dataset.SCENE_FILE).stat().st_size
    print(f"{n} scenes, {spp} per shard, {n // spp} shards; per scene: scene.json "
          f"{scene_json / 1024:.1f} kB, "
          f"frames {frame_bytes / 1024:.0f} kB")
    rows = []
    first, t = timed(dataset.seal_dataset, root)
    rows.append(("first seal (every scene hashed)", t, first))
    again, t = timed(dataset.seal_dataset, root)
    rows.append(("reseal, nothing changed", t, again))
    add_scenes(root, source, range(n, n + spp), spp)
    grown, t = timed(dataset.seal_dataset, root)
    rows.append((f"reseal after {spp} new scenes (one shard)", t, grown))
    report, t_verify = timed(dataset.verify_dataset, root)
    assert not report.problems, report.problems[:3]
    for what, seconds, result in rows:
        total = result.index["scene_count"]
        print(f"{what:45s} {seconds:7.3f} s  {1000 * seconds / total:6.3f} ms/scene  "
              f"({len(result.shards_written)} shard.json written, {result.scenes_hashed} scenes hashed)")
    total = report.scenes
    print(f"{'verify (every file hashed)':45s} {t_verify:7.3f} s  {1000 * t_verify / total:6.3f} ms/scene")
    blob = (source / "frame_0.exr").read_bytes() * 64
    _, t_hash = timed(lambda: hashlib.sha256(blob).hexdigest())
    print(f"sha256: {len(blob) / t_hash / 1e6:.0f} MB/s here, so a 4-frame full-resolution scene (31.6 MB) "
          f"costs about {31.6e6 / (len(blob) / t_hash) * 1000:.0f} ms to hash")
    if args.work is None:
        shutil.rmtree(work)
    return 0


if __name__ == "__main__":
    sys.exit(main())
