"""Benchmark: the generator's work around the render, per scene, at half and full Structure Core size.

    python -m bench.generate_stages [--repeats 5]

Stages timed (medians of --repeats runs): sampling a SceneSpec (the default config's object count),
post-rendering four frames (sensor model, masks, ground truth) and writing the scene (four EXR
frames + scene.json, atomically). The raw passes are a plausible synthetic frame (a slanted wall
with boxes, dots with 1/z^2 falloff): the cost of these stages does not depend on what was rendered.
Compare the total with the render itself (bench.render_speed; docs/RENDERING.md: 2.5-3 s per frame
at 1216 x 896 on two cores) to see what share of a scene's time is not Cycles.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time

import numpy as np

from dotsim import dataset
from generator.config import config_from_dict
from generator.post_render import make_frame
from generator.sample_scene import STREAM_SENSOR, SceneResources, build_rig, sample_scene_spec, scene_rng


def raw_frame(rig, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Raw passes with realistic structure: depth of a wall with boxes, dotted projector light."""
    h, w = rig.camera.height, rig.camera.width
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    depth = 3.0 + 0.8 * u / w + 0.4 * v / h
    for _ in range(8):
        y, x = rng.integers(0, h // 2), rng.integers(0, w // 2)
        depth[y:y + h // 6, x:x + w // 6] = rng.uniform(0.5, 2.5)
    flood = (0.6 / depth**2).astype(np.float32)
    dots = (rng.random((h, w)) < 0.08).astype(np.float32)
    projector = flood * dots
    # all of it direct light (no bounces in this synthetic frame)
    return {"projector": projector, "flood": flood, "ambient": np.full((h, w), 0.01, np.float32),
            "depth": depth, "projector_direct": projector, "flood_direct": flood}


def median_seconds(function, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def stage_times(scale: float, repeats: int) -> dict[str, float]:
    config = config_from_dict({"rig": {"scale": scale}})
    rig = build_rig(config)
    resources = SceneResources("/bench/pattern.png", "0" * 64)
    spec = sample_scene_spec(config, 0, 0, "train", resources)
    raws = [raw_frame(rig, np.random.default_rng(k)) for k in range(4)]
    frames = [make_frame(raw, spec, scene_rng(0, 0, STREAM_SENSOR)) for raw in raws]
    stored = spec.to_dict()
    meta = {"split": "train", "rig": stored["rig"], "pattern": {}, "poses": stored["poses"],
            "config": config.to_dict(), "objects": stored["objects"]}
    with tempfile.TemporaryDirectory() as tmp:
        counter = iter(range(10**6))
        return {
            "sample SceneSpec": median_seconds(
                lambda: sample_scene_spec(config, next(counter), 0, "train", resources), repeats),
            "post-render 4 frames": median_seconds(
                lambda: [make_frame(raw, spec, scene_rng(0, 0, STREAM_SENSOR)) for raw in raws],
                repeats),
            "write scene": median_seconds(lambda: dataset.write_scene(tmp, next(counter), meta, frames),
                                          repeats),
        }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    half = stage_times(0.5, args.repeats)
    full = stage_times(1.0, args.repeats)
    print(f"seconds per scene, median of {args.repeats} (4 frames per scene)")
    print(f"{'stage':<22}{'608x448':>10}{'1216x896':>10}{'ratio':>8}")
    for name in half:
        print(f"{name:<22}{half[name]:>10.3f}{full[name]:>10.3f}{full[name] / half[name]:>8.2f}")
    total_half, total_full = sum(half.values()), sum(full.values())
    print(f"{'total':<22}{total_half:>10.3f}{total_full:>10.3f}{total_full / total_half:>8.2f}")


if __name__ == "__main__":
    main()
