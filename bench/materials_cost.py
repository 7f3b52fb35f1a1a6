"""What labels, normals and transparent / metal / IR-dark objects cost per frame: the same scene
rendered, post-rendered and encoded without and with each, side by side (docs/CONFIG.md "Materials",
docs/RENDERING.md "Labels, normals and materials").

    python -m bench.materials_cost [--sizes 640,1216] [--objects 300] [--repeats 3] [--no-lights]

bench.render_speed's scene (a wall 6 m away, N textured primitives from 0.8 to 5 m, two 50 W extra
lights unless --no-lights: then the one-render recipe) seen by a Structure Core scaled to each width
from four poses 2 cm apart, one SceneRenderer. The ways: plain; `labels` ([render] labels); `normals`
([render] normals); `materials`: every fifth object glass, the next metal, the next IR-dark (60 %
of the objects, untextured where glass or metal; the labels on, as such a scene needs). Each round
renders the whole scene (build and four frames) once each way, the ways taking turns in rotating
order, post-renders its frames (generator.post_render.make_frame, one thread) and encodes them
(dotsim.dataset.encode_frame, zstd). Reported per frame, median over rounds: wall seconds of the
render, CPU seconds of this process (every render thread), wall seconds of the post-render and of
the encoding, and the bytes of a frame file, each with its ratio to the plain way's. It also says
whether the labels' and normals' renders left the plain way's raw passes bit for bit as they were
(they should: the data passes change no sample).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from bench.render_speed import add_side_by_side_options, bench_rig, bench_spec, scene_poses, write_inputs
from dotsim.dataset import encode_frame
from dotsim.rig.presets import get_preset
from generator.post_render import frame_channels, frame_shapes, make_frame
from generator.sample_scene import frame_streams
from generator.scene_spec import SceneSpec

FULL = get_preset("structure_core")
# Every fifth object from the first (after the wall) glass, from the second metal, from the third IR-dark.
KINDS = {0: "transparent", 1: "metal", 2: "ir_dark"}


def scenes(rig, inputs, objects: int, lights: bool) -> dict[str, SceneSpec]:
    """The benchmark scene each way."""
    spec = bench_spec(rig, inputs, objects, lights=lights)
    spec["sensor"]["pixel_scale"] = rig.camera.width / FULL.camera.width
    spec["poses"] = scene_poses()
    plain = SceneSpec.from_dict(spec)
    for k, obj in enumerate(spec["objects"][1:]):
        kind = KINDS.get(k % 5)
        if kind is None or (kind == "transparent" and obj["mesh"]["shape"] == "plane"):
            continue
        material = obj["material"]
        material.update(kind=kind, ior=1.5)
        if kind in ("transparent", "metal"):
            material.update(texture=None, albedo=0.95 if kind == "transparent" else 0.9, roughness=0.02)
        else:
            material.update(albedo=0.005, specular=0.0)
    spec["render"]["labels"] = True
    return {"plain": plain, "labels": replace(plain, render=replace(plain.render, labels=True)),
            "normals": replace(plain, render=replace(plain.render, normals=True)),
            "materials": SceneSpec.from_dict(spec)}


def one_round(renderer, spec: SceneSpec) -> tuple[dict[str, float], list[dict]]:
    """Render, post-render and encode every frame of `spec` once: seconds and bytes per frame, and
    the raw passes."""
    wall, cpu = time.perf_counter(), time.process_time()
    raws = renderer.render(spec)
    render_wall, render_cpu = time.perf_counter() - wall, time.process_time() - cpu
    start = time.perf_counter()
    frames = [make_frame(raw, spec, frame_streams(0, spec, k)) for k, raw in enumerate(raws)]
    post = time.perf_counter() - start
    start = time.perf_counter()
    sizes = [len(encode_frame(frame, frame_shapes(spec), frame_channels(spec), rig=spec.rig.to_dict()))
             for frame in frames]
    encode = time.perf_counter() - start
    count = len(raws)
    return ({"render_s": render_wall / count, "render_cpu_s": render_cpu / count, "post_s": post / count,
             "encode_s": encode / count, "bytes": float(np.mean(sizes))}, raws)


def side_by_side(renderer, specs: dict[str, SceneSpec], repeats: int) -> tuple[dict, dict]:
    """`repeats` rounds of one_round for each way of `specs` (the ways taking turns in rotating order,
    so drift over the run falls on all alike): (way -> measure -> median over rounds, way -> the
    last round's raw passes)."""
    ways = list(specs)
    runs, raws = {way: [] for way in ways}, {}
    for round_index in range(repeats):
        shift = round_index % len(ways)
        for way in ways[shift:] + ways[:shift]:
            run, raws[way] = one_round(renderer, specs[way])
            runs[way].append(run)
    medians = {way: {key: statistics.median(run[key] for run in runs[way]) for key in runs[way][0]}
               for way in ways}
    return medians, raws


def print_ratios(medians: dict) -> None:
    """One line per measure: the first way's median, then each other way's with its ratio to it."""
    plain_way, *others = medians
    for key, label in (("render_s", "render, wall s"), ("render_cpu_s", "render, CPU s"),
                       ("post_s", "post-render, wall s"), ("encode_s", "encode, wall s"),
                       ("bytes", "frame file, bytes")):
        plain = medians[plain_way][key]
        cells = [f"{way} {medians[way][key]:.4g} ({medians[way][key] / plain:.2f}x)" for way in others]
        print(f"  {label:>20}: {plain_way} {plain:.4g}  " + "  ".join(cells), flush=True)


def same_raw(plain: list[dict], other: list[dict]) -> bool:
    """Whether every raw pass of the plain way is bit for bit the same in the other way's frames."""
    return all(np.array_equal(a[name], b[name]) for a, b in zip(plain, other, strict=True) for name in a)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.materials_cost",
                                     description=__doc__.split("\n\n")[0])
    add_side_by_side_options(parser, FULL.camera.width)
    args = parser.parse_args(argv)

    from generator.blender.render import SceneRenderer

    lights = not args.no_lights
    with tempfile.TemporaryDirectory(prefix="dotsim-bench-") as tmp, SceneRenderer() as renderer:
        for width in (int(w) for w in args.sizes.split(",")):
            rig = bench_rig(width)
            inputs = write_inputs(rig, Path(tmp))
            medians, raws = side_by_side(renderer, scenes(rig, inputs, args.objects, lights), args.repeats)
            print(f"\n{rig.camera.width} x {rig.camera.height}, {args.objects} objects, "
                  f"{'two extra lights' if lights else 'no extra light'}, median of {args.repeats} "
                  f"rounds (per frame):")
            print_ratios(medians)
            for way in ("labels", "normals"):
                verdict = "bit for bit the same" if same_raw(raws["plain"], raws[way]) else "DIFFERENT"
                print(f"  plain raw passes with {way} on: {verdict}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
