"""What the colour camera ([render] rgb) costs per frame: the same scene rendered, post-rendered and
encoded without and with it, side by side (docs/RENDERING.md "Colour camera").

    python -m bench.rgb_cost [--sizes 640,1280] [--objects 300] [--repeats 3] [--no-lights]

bench.render_speed's scene (a wall 6 m away, N textured primitives from 0.8 to 5 m, two 50 W extra
lights unless --no-lights: then the one-render recipe, and the colour image is lit by the world alone)
seen by a RealSense D415 (the RGB-D preset whose IR camera is widest, 1280 px; its colour camera 1920 x
1080 at full size) scaled to each IR width, its colour camera by the same factor, from four poses 2 cm
apart, one SceneRenderer. The ways: plain (no colour camera); `rgb` ([render] rgb, the colour render at
the scene's 1 sample); `rgb_16` (rgb_samples = 16: a less noisy colour image). Every opaque surface has a
visible colour (a tint) in all three ways, which the plain way does not render. Each round renders the
whole scene (build and four frames) once each way, the ways taking turns in rotating order, post-renders
its frames (generator.post_render.make_frame, one thread) and encodes them (dotsim.dataset.encode_frame,
zstd). Reported per frame, median over rounds: wall seconds of the render, CPU seconds of this process
(every render thread), wall seconds of the post-render and of the encoding, and the bytes of a frame
file, each with its ratio to the plain way's. It also says whether the colour camera left the plain
way's raw passes bit for bit as they were (it should: its render comes after the IR renders).
"""

from __future__ import annotations

import argparse
import tempfile
from dataclasses import replace
from pathlib import Path

from bench.materials_cost import print_ratios, same_raw, side_by_side
from bench.render_speed import add_side_by_side_options, bench_rig, bench_spec, scene_poses, write_inputs
from dotsim.rig.presets import PRESET_COLOUR_CAMERAS, get_preset
from generator.scene_spec import SceneSpec

PRESET = "realsense_d415"
FULL = get_preset(PRESET)
WAYS = ("plain", "rgb", "rgb_16")
TINTS = ((0.9, 0.4, 0.3), (0.3, 0.8, 0.4), (0.4, 0.5, 0.9), (0.9, 0.9, 0.8))


def scenes(rig, inputs, objects: int, lights: bool) -> dict[str, SceneSpec]:
    """The benchmark scene each way."""
    spec = bench_spec(rig, inputs, objects, lights=lights)
    spec["sensor"]["pixel_scale"] = rig.camera.width / FULL.camera.width
    spec["poses"] = scene_poses()
    for k, obj in enumerate(spec["objects"]):
        obj["material"]["tint"] = list(TINTS[k % len(TINTS)])
    plain = SceneSpec.from_dict(spec)
    colour = PRESET_COLOUR_CAMERAS[PRESET].scaled(rig.camera.width / FULL.camera.width)
    rgb = replace(plain, render=replace(plain.render, rgb=True), colour_camera=colour)
    return {"plain": plain, "rgb": rgb, "rgb_16": replace(rgb, render=replace(rgb.render, rgb_samples=16))}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.rgb_cost", description=__doc__.split("\n\n")[0])
    add_side_by_side_options(parser, FULL.camera.width)
    args = parser.parse_args(argv)

    from generator.blender.render import SceneRenderer

    lights = not args.no_lights
    with tempfile.TemporaryDirectory(prefix="dotsim-bench-") as tmp, SceneRenderer() as renderer:
        for width in (int(w) for w in args.sizes.split(",")):
            rig = bench_rig(width, PRESET)
            inputs = write_inputs(rig, Path(tmp))
            specs = scenes(rig, inputs, args.objects, lights)
            medians, raws = side_by_side(renderer, specs, args.repeats)
            colour = specs["rgb"].colour_camera.intrinsics
            print(f"\nIR {rig.camera.width} x {rig.camera.height}, colour {colour.width} x {colour.height}, "
                  f"{args.objects} objects, {'two extra lights' if lights else 'no extra light'}, median of "
                  f"{args.repeats} rounds (per frame):")
            print_ratios(medians)
            for way in WAYS[1:]:
                ir = [{name: a for name, a in raw.items() if name != "rgb"} for raw in raws[way]]
                verdict = "bit for bit the same" if same_raw(raws["plain"], ir) else "DIFFERENT"
                print(f"  plain raw passes with {way} on: {verdict}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
