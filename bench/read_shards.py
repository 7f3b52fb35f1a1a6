"""Benchmark: frames per second reading a dotsim dataset (all channels), with and without checksums.

    python -m bench.read_shards [--shards 2] [--scenes 3] [--repeats 5] [--compression]

Writes a small dataset of plausible full-resolution (Structure Core, 1216 x 896) frames to a temp
dir -- a dot image with falloff, sensor noise and 10-bit quantisation, a slanted wall with boxes --
then reads every frame several times and prints the median frames/s for each way of reading and
their ratio. --compression also compares EXR compressions (size, write and read time per frame).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from dotsim import dataset as ds
from dotsim.masks import edge_mask, visibility_mask
from dotsim.rig.geometry import depth_to_disparity, depth_to_projector_column, is_ground_truth
from dotsim.rig.presets import get_preset


def synthetic_frame(rig, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """A frame with the statistics that matter for compression: noisy quantised dots, smooth depth."""
    h, w = rig.camera.height, rig.camera.width
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    depth = 3.0 + 0.8 * (u / w) + 0.4 * (v / h)  # slanted wall
    for _ in range(6):  # boxes in front of it
        y, x = rng.integers(0, h - 120), rng.integers(0, w - 160)
        depth[y:y + rng.integers(60, 120), x:x + rng.integers(80, 160)] = rng.uniform(0.8, 2.5)
    depth[: h // 10, : w // 8] = np.inf  # a window: nothing hit
    impulses = np.zeros((h, w), np.float32)
    impulses[rng.integers(0, h, 40000), rng.integers(0, w, 40000)] = 1.0
    dots = cv2.GaussianBlur(impulses, (0, 0), 0.8) * 2 * np.pi * 0.8**2
    albedo = rng.uniform(0.3, 0.9)
    hit = np.isfinite(depth)
    falloff = albedo / np.square(np.where(hit, depth, 1.0)) * hit
    ambient = (0.02 + 0.01 * v / h) * hit
    flood = ambient + 0.5 * falloff
    level = ambient + 2.0 * falloff * dots
    level = level + rng.standard_normal((h, w)) * np.sqrt(0.003**2 + 0.01**2 * level)
    ir = np.round(np.clip(level, 0, 1) * 1023) / 1023
    gt = np.where(is_ground_truth(depth, rig.max_depth), depth, np.nan)
    return {"ir": ir, "ambient": ambient, "flood": flood, "depth": depth,
            "visibility": visibility_mask(ambient, flood, depth=depth), "edge": edge_mask(depth),
            "projector_column": depth_to_projector_column(gt, rig), "disparity": depth_to_disparity(gt, rig)}


def scene_meta(rig, index: int) -> dict:
    eye = np.eye(4).tolist()
    return {"split": "train", "seed": index, "rig": rig.to_dict(), "poses": [eye] * 4,
            "pattern": {"source": "bench", "sha256": "0" * 64, "width": rig.projector.width,
                        "height": rig.projector.height, "params": {}}}


def median_rates(readers: dict, count: int, repeats: int) -> dict[str, float]:
    """Median frames/s of each reader; the readers take turns so background load hits all alike."""
    times: dict[str, list[float]] = {name: [] for name in readers}
    for _ in range(repeats):
        for name, fn in readers.items():
            start = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - start)
    return {name: count / statistics.median(t) for name, t in times.items()}


def compare_compressions(rig, frame: dict, tmp: Path, repeats: int) -> None:
    import OpenEXR

    shape = (rig.camera.height, rig.camera.width)
    print(f"{'compression':<18}{'MB/frame':>10}{'write ms':>10}{'read ms':>10}")
    for name in ("NO_COMPRESSION", "ZIP_COMPRESSION", "ZIPS_COMPRESSION", "PIZ_COMPRESSION",
                 "ZSTD_COMPRESSION", "HTJ2K32_COMPRESSION"):
        path = tmp / f"{name}.exr"
        writes, reads = [], []
        for _ in range(repeats):
            start = time.perf_counter()
            ds.write_frame_file(path, frame, shape, compression=name, rig=rig.to_dict())
            writes.append(time.perf_counter() - start)
            start = time.perf_counter()
            OpenEXR.File(str(path), separate_channels=True).channels()
            reads.append(time.perf_counter() - start)
        print(f"{name:<18}{path.stat().st_size / 1e6:>10.2f}{1e3 * statistics.median(writes):>10.0f}"
              f"{1e3 * statistics.median(reads):>10.0f}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.read_shards", description=__doc__.split("\n")[0])
    parser.add_argument("--shards", type=int, default=2, help="shards to write (default 2)")
    parser.add_argument("--scenes", type=int, default=3, help="scenes per shard (default 3)")
    parser.add_argument("--repeats", type=int, default=5, help="timed passes over all frames (default 5)")
    parser.add_argument("--compression", action="store_true", help="also compare EXR compressions")
    args = parser.parse_args(argv)
    rig = get_preset("structure_core")
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory(prefix="dotsim-bench-") as tmp:
        root = Path(tmp) / "dataset"
        start = time.perf_counter()
        n_scenes = args.shards * args.scenes
        for index in range(n_scenes):
            frames = [synthetic_frame(rig, rng) for _ in range(4)]
            ds.write_scene(root, index, scene_meta(rig, index), frames, scenes_per_shard=args.scenes)
        index = ds.seal_dataset(root).index
        size = sum(p.stat().st_size for p in root.rglob("*.exr")) / index["frame_count"] / 1e6
        print(f"wrote {n_scenes} scenes ({index['frame_count']} frames, {rig.camera.width} x "
              f"{rig.camera.height}, {size:.2f} MB/frame) in {time.perf_counter() - start:.1f} s")
        n_frames = index["frame_count"]

        def read_all(verify: bool):
            dataset = ds.open_dataset(root, verify=verify)
            for ref in dataset.scenes:
                for path in ref.frame_paths:
                    ds.read_frame(path, verify=verify)

        def read_train_channels():
            for ref in ds.open_dataset(root).scenes:
                for path in ref.frame_paths:
                    ds.read_frame(path, channels=("ir", "visibility", "edge", "projector_column"))

        read_all(True)  # warm the page cache: we measure decoding, not the disk
        rates = median_rates({"all channels, sha256 verified": lambda: read_all(True),
                              "all channels, no verification": lambda: read_all(False),
                              "4 training channels, verified": read_train_channels},
                             n_frames, args.repeats)
        base = rates["all channels, no verification"]
        for name, rate in rates.items():
            print(f"{name:<32} {rate:7.1f} frames/s  ({rate / base:.2f}x unverified)")
        if args.compression:
            compare_compressions(rig, synthetic_frame(rig, rng), Path(tmp), args.repeats)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
