"""What a second Cycles pass per frame costs next to the path-traced render: the floor under any way
of getting the projector's direct light from a render of its own (docs/RENDERING.md, "Missing
dots").

    python -m bench.second_pass [--sizes 640,1216] [--objects 300] [--repeats 5]

bench.render_speed's scene (N textured objects before a wall, two 50 W extra lights), one pose,
one SceneRenderer. Per size and round, each kind of render runs once to sync its settings into
Cycles, then once timed (wall seconds; median over rounds):
- path-traced: the frame's path-traced render, as the renderer makes it (all lights, bounces,
  compositor, EXR written and read);
- path-traced with direct passes: the one render of a scene without extra lights (or with
  [render] direct_light = "shared"), as the renderer makes it: all light as rendered, the direct
  passes on and written apart (no direct render follows);
- direct: the spot's direct light, as the renderer makes it (no bounces, extra lights hidden);
- bare: the least a full-size pass can be: camera rays only (no light, no bounce, one emission
  material for every object, no compositor);
- bare, half size: the same at half the width and height.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from bench.render_speed import bench_rig, bench_spec, write_inputs
from generator.blender.frame_recipe import ALL_LIGHT_RENDER, DIRECT_LIGHT_RENDER, INDIRECT_LIGHT_RENDER
from generator.scene_spec import SceneSpec


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.second_pass", description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="640,1216", help="camera widths (default 640,1216)")
    parser.add_argument("--objects", type=int, default=300, help="objects in the scene (default 300)")
    parser.add_argument("--repeats", type=int, default=5, help="timed rounds (default 5)")
    args = parser.parse_args(argv)

    from generator.blender.bare_pass import bare_pass
    from generator.blender.render import SceneRenderer

    with tempfile.TemporaryDirectory(prefix="dotsim-bench-") as tmp, SceneRenderer() as renderer:
        kinds = {
            "path-traced": lambda: renderer._set_for(INDIRECT_LIGHT_RENDER),
            "path-traced with direct passes": lambda: renderer._set_for(ALL_LIGHT_RENDER),
            "direct": lambda: renderer._set_for(DIRECT_LIGHT_RENDER),
            "bare": lambda: bare_pass(renderer, 100),
            "bare, half size": lambda: bare_pass(renderer, 50),
        }
        for width in (int(w) for w in args.sizes.split(",")):
            rig = bench_rig(width)
            spec = SceneSpec.from_dict(bench_spec(rig, write_inputs(rig, Path(tmp)), args.objects))
            renderer.place_rig(renderer.setup(spec)[0])
            seconds = {kind: [] for kind in kinds}
            for _ in range(args.repeats):
                for kind, settings in kinds.items():
                    with settings():
                        renderer._render_channels()  # syncs the changed settings into Cycles
                        start = time.perf_counter()
                        renderer._render_channels()
                        seconds[kind].append(time.perf_counter() - start)
            base = statistics.median(seconds["path-traced"])
            print(f"\n{rig.camera.width} x {rig.camera.height}, {args.objects} objects, "
                  f"median of {args.repeats} (s per render, and against the path-traced render):")
            for kind, values in seconds.items():
                median = statistics.median(values)
                print(f"  {kind:>30}: {median:.3f} s  {median / base:.2f}x   "
                      f"(runs {' '.join(f'{v:.3f}' for v in values)})", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
