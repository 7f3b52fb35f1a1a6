"""Render cost against object count (default settings: with extra lights, two renders per frame).

    python -m bench.render_objects [--width 640] [--counts 100,300,1000] [--repeats 3]

Same scene recipe as bench.render_speed (textured random primitives before a wall, two extra point
lights). For each count: scene build time and the median seconds per frame over `repeats` frames
(after the first frame, which also syncs the new scene into Cycles; reported separately).
Goal (issue 3): 1000 objects cost at most 1.5x the time of 100.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

from bench.render_speed import bench_rig, bench_spec, timed, write_inputs
from generator.scene_spec import SceneSpec


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.render_objects", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument(
        "--width", type=int, default=640, help="camera width (Structure Core scaled; default 640)"
    )
    parser.add_argument("--counts", default="100,300,1000", help="object counts (default 100,300,1000)")
    parser.add_argument("--repeats", type=int, default=3, help="timed frames per count (default 3)")
    args = parser.parse_args(argv)

    from generator.blender.render import SceneRenderer

    counts = [int(c) for c in args.counts.split(",")]
    rows = []
    rig = bench_rig(args.width)
    with tempfile.TemporaryDirectory(prefix="dotsim-bench-") as tmp, SceneRenderer() as renderer:
        inputs = write_inputs(rig, Path(tmp))
        for count in counts:
            spec = bench_spec(rig, inputs, count)
            (poses,), build = timed(lambda spec=spec: [renderer.setup(SceneSpec.from_dict(spec))])
            pose = poses[0]
            _, first = timed(lambda pose=pose: renderer.render_frame(pose))
            frames = [timed(lambda pose=pose: renderer.render_frame(pose))[1] for _ in range(args.repeats)]
            rows.append((count, build, first, statistics.median(frames)))
            print(
                f"{count} objects: build {build:.2f} s, first frame {first:.2f} s, frame {rows[-1][3]:.2f} s",
                flush=True,
            )
    base = rows[0][3]
    print(f"\nsummary at {rig.camera.width}x{rig.camera.height} (median of {args.repeats} frames)")
    print(f"{'objects':>8} {'build s':>8} {'1st frame s':>12} {'frame s':>8} {'vs ' + str(counts[0]):>8}")
    for count, build, first, frame in rows:
        print(f"{count:>8} {build:>8.2f} {first:>12.2f} {frame:>8.2f} {frame / base:>7.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
