"""What the second IR camera costs per frame: the same scene rendered and post-rendered with the rig's
own camera alone and with its stereo pair, side by side (docs/RENDERING.md "The stereo pair").

    python -m bench.stereo_cost [--sizes 640,1280] [--objects 300] [--repeats 3] [--no-lights]

bench.render_speed's scene (a wall 6 m away, N textured primitives from 0.8 to 5 m, two 50 W extra
lights unless --no-lights: then the one-render recipe) seen by a RealSense D415 (realsense_d415,
scaled to each width) from four poses 2 cm apart, one SceneRenderer. Each round renders the whole
scene (build and four frames) once each way, the two ways taking turns in alternating order, and
post-renders its frames (generator.post_render.make_frame, one thread). Reported per frame, median
over rounds: wall seconds of the render, CPU seconds of this process (every render thread) and wall
seconds of the post-render, each way, and the stereo way's ratio to the mono way's.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from bench.render_speed import add_side_by_side_options, bench_rig, bench_spec, scene_poses, write_inputs
from dotsim.rig.presets import get_preset
from generator.post_render import make_frame
from generator.sample_scene import frame_streams
from generator.scene_spec import SceneSpec, camera_views

FULL = get_preset("realsense_d415")
WAYS = ("mono", "stereo")


def scene(rig, inputs, objects: int, lights: bool, stereo: bool) -> SceneSpec:
    """The benchmark scene with the rig's own camera alone or its stereo pair."""
    spec = bench_spec(rig, inputs, objects, lights=lights)
    spec["sensor"]["pixel_scale"] = rig.camera.width / FULL.camera.width
    spec["poses"] = scene_poses()
    spec["cameras"] = [camera.to_dict() for camera in camera_views(rig, stereo)]
    return SceneSpec.from_dict(spec)


def one_round(renderer, spec: SceneSpec) -> dict[str, float]:
    """Render and post-render every frame of `spec` once: seconds per frame."""
    wall, cpu = time.perf_counter(), time.process_time()
    raws = renderer.render(spec)
    render_wall, render_cpu = time.perf_counter() - wall, time.process_time() - cpu
    start = time.perf_counter()
    for k, raw in enumerate(raws):
        make_frame(raw, spec, frame_streams(0, spec, k))
    post = time.perf_counter() - start
    count = len(raws)
    return {"render_s": render_wall / count, "render_cpu_s": render_cpu / count, "post_s": post / count}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.stereo_cost", description=__doc__.split("\n\n")[0])
    add_side_by_side_options(parser, FULL.camera.width)
    args = parser.parse_args(argv)

    from generator.blender.render import SceneRenderer

    lights = not args.no_lights
    with tempfile.TemporaryDirectory(prefix="dotsim-bench-") as tmp, SceneRenderer() as renderer:
        for width in (int(w) for w in args.sizes.split(",")):
            rig = bench_rig(width, "realsense_d415")
            inputs = write_inputs(rig, Path(tmp))
            specs = {way: scene(rig, inputs, args.objects, lights, way == "stereo") for way in WAYS}
            runs = {way: [] for way in WAYS}
            for round_index in range(args.repeats):
                for way in WAYS if round_index % 2 == 0 else WAYS[::-1]:
                    runs[way].append(one_round(renderer, specs[way]))
            print(f"\n{rig.camera.width} x {rig.camera.height}, {args.objects} objects, "
                  f"{'two extra lights' if lights else 'no extra light'}, median of {args.repeats} "
                  f"rounds (s per frame):")
            medians = {way: {key: statistics.median(run[key] for run in runs[way]) for key in runs[way][0]}
                       for way in WAYS}
            for key, label in (("render_s", "render, wall"), ("render_cpu_s", "render, CPU"),
                               ("post_s", "post-render, wall")):
                mono, stereo = medians["mono"][key], medians["stereo"][key]
                print(f"  {label:>18}: mono {mono:.3f}  stereo {stereo:.3f}  ({stereo / mono:.2f}x)",
                      flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
