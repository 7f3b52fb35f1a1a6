"""Seconds per frame and projector-pass quality of the one-render way against three renders.

    python -m bench.render_speed [--sizes 640,1216] [--objects 300] [--repeats 3] [--reference-samples 128]

Scene: a wall 6 m away and N random textured primitives between 0.8 and 5 m (demo_scenes.clutter),
Structure Core rig scaled to each width, default procedural pattern, projector 100 W, flood 100 W,
world strength 0.05 and two extra point lights (50 W each) unless --no-lights.

Ways compared on the same scene with four poses (2 cm apart), each timed `repeats` times over a
whole scene (build + 4 frames, divided by 4; median reported):
- one render (SceneRenderer): projector = R, flood = G, ambient = B of one Cycles render.
- three renders (GigaDepth's Unity way): projector on, projector off, rectangle on, all lights
  white; projector = on - off and flood = rectangle - off, off = ambient. Emulated with the same
  renderer by switching powers and summing R + G + B (materials are grey, so the sum is exactly
  what white lights give).
Quality: correlation of each way's projector pass with a projector-only render at
--reference-samples samples (projector alone: flood, world and extra lights off) over flood-lit
pixels (flood above 5% of its 99th percentile).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import statistics
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from dotsim.patterns import generate_dot_pattern
from dotsim.rig.geometry import Rig
from dotsim.rig.presets import get_preset
from generator.blender import demo_scenes as ds
from generator.scene_spec import SceneSpec

FULL_WIDTH = 1216


def bench_rig(width: int, preset: str = "structure_core") -> Rig:
    """The preset's rig scaled to `width` camera pixels (its own width, 1216 for Structure Core, = full
    size)."""
    rig = get_preset(preset)
    return rig if width == rig.camera.width else rig.scaled(width / rig.camera.width)


def write_inputs(rig: Rig, folder: Path, n_textures: int = 8) -> tuple[str, str, list[str]]:
    """Default procedural pattern at the rig's projector size and a few random grey textures
    (blurred noise PNGs); returns (pattern path, pattern sha256, texture paths)."""
    pattern = generate_dot_pattern(rig.projector.width, rig.projector.height, seed=0)
    pattern_path = folder / f"pattern_{rig.projector.width}.png"
    pattern.save_png(pattern_path)
    rng = np.random.default_rng(0)
    textures = []
    for k in range(n_textures):
        noise = cv2.GaussianBlur(rng.random((256, 256)).astype(np.float32), (0, 0), 1 + 2 * k)
        noise = (noise - noise.min()) / (noise.max() - noise.min())
        path = folder / f"texture_{k}.png"
        cv2.imwrite(str(path), (noise * 255).astype(np.uint8))
        textures.append(str(path))
    return str(pattern_path), pattern.sha256, textures



def add_side_by_side_options(parser: argparse.ArgumentParser, full_width: int) -> None:
    """The options of a benchmark that renders one scene several ways, taking turns (bench.stereo_cost,
    bench.materials_cost): camera widths up to the rig's full `full_width`, objects, rounds, lights."""
    sizes = f"640,{full_width}"
    parser.add_argument("--sizes", default=sizes,
                        help=f"camera widths, comma-separated, at most {full_width} (default {sizes})")
    parser.add_argument("--objects", type=int, default=300, help="random objects (default 300)")
    parser.add_argument("--repeats", type=int, default=3, help="rounds per way (default 3)")
    parser.add_argument("--no-lights", action="store_true", help="no extra point lights (the one-render "
                        "recipe)")

def bench_spec(
    rig: Rig,
    inputs: tuple[str, str, list[str]],
    n_objects: int,
    *,
    seed: int = 0,
    samples: int = 1,
    lights: bool = True,
    threads: int = 0,
) -> dict:
    """The benchmark scene (see the module docstring) as a SceneSpec."""
    pattern_path, sha, textures = inputs
    point_lights = (
        [{"type": "POINT", "location": [x, -1.5, 2.0], "power": 50.0, "radius": 0.1} for x in (-1.5, 1.5)]
        if lights
        else []
    )
    spec = ds.base_spec(
        rig.to_dict(),
        pattern_path,
        sha,
        samples=samples,
        seed=seed,
        projector_power=100.0,
        flood_power=100.0,
        world_strength=0.05,
        lights=point_lights,
        threads=threads,
        pixel_scale=rig.camera.width / FULL_WIDTH,
    )
    objects = ds.clutter(n_objects, seed=seed, depth_range=(0.8, 5.0), half_fov=0.55)
    for k, obj in enumerate(objects):
        obj["material"]["texture"] = {
            "path": textures[k % len(textures)],
            "scale": 1.0 + k % 3,
            "contrast": 0.6,
        }
    spec["objects"] = [ds.wall(6.0)] + objects
    return spec


def correlation(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    a = a[mask] - a[mask].mean()
    b = b[mask] - b[mask].mean()
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))


def flood_lit(flood: np.ndarray) -> np.ndarray:
    return flood > 0.05 * np.percentile(flood, 99)


def timed(function):
    start = time.perf_counter()
    result = function()
    return result, time.perf_counter() - start


def three_renders(renderer, pose: np.ndarray, spec: dict) -> tuple[np.ndarray, np.ndarray]:
    """GigaDepth's way: on / off / rectangle renders with white light, differences give the passes."""
    projector_power, flood_power = spec["projector"]["power"], spec["flood"]["power"]
    totals = []
    for powers in ((projector_power, 0.0), (0.0, 0.0), (0.0, flood_power)):
        renderer.projector.set_powers(*powers)
        renderer.refresh()
        frame = renderer.render_frame(pose)
        totals.append(frame["projector"] + frame["flood"] + frame["ambient"])
    renderer.projector.set_powers(projector_power, flood_power)
    renderer.refresh()
    on, off, rectangle = totals
    return on - off, rectangle - off


def one_render_scene(renderer, spec: dict) -> tuple[np.ndarray, np.ndarray]:
    """Build the scene and render all its frames the one-render way; frame 0's projector and flood."""
    frames = renderer.render(SceneSpec.from_dict(spec))
    return frames[0]["projector"], frames[0]["flood"]


def three_renders_scene(renderer, spec: dict) -> tuple[np.ndarray, np.ndarray]:
    """Build the scene and render all its frames the three-renders way; frame 0's passes."""
    poses = renderer.setup(SceneSpec.from_dict(spec))
    passes = [three_renders(renderer, pose, spec) for pose in poses]
    return passes[0]


def scene_poses(count: int = 4) -> list:
    """`count` rig poses 2 cm apart along x (a scene's small sensor motion)."""
    poses = []
    for k in range(count):
        pose = np.eye(4)
        pose[0, 3] = 0.02 * k
        poses.append(pose.tolist())
    return poses


def reference_projector(renderer, spec: dict, samples: int, cache: Path | None = None) -> np.ndarray:
    """Projector-only render (flood, world and extra lights off) at `samples` samples; kept in
    `cache` (a folder) under a hash of the spec when given, since it takes minutes."""
    reference = dict(
        spec,
        render=dict(spec["render"], samples=samples),
        flood={"power": 0.0},
        world={"strength": 0.0},
        lights=[],
    )
    if cache is not None:
        # File names only: the inputs live in a fresh temp folder on every run.
        text = re.sub(r'"/[^"]*/([^"/]+)"', r'"\1"', json.dumps(reference, sort_keys=True))
        key = hashlib.sha256(text.encode()).hexdigest()[:16]
        path = cache / f"reference_{key}.npy"
        if path.exists():
            return np.load(path)
    projector = renderer.render(SceneSpec.from_dict(reference))[0]["projector"]
    if cache is not None:
        cache.mkdir(parents=True, exist_ok=True)
        np.save(path, projector)
    return projector


def measure(
    renderer,
    rig: Rig,
    inputs,
    n_objects: int,
    repeats: int,
    reference_samples: int,
    lights: bool,
    cache: Path | None = None,
) -> dict:
    """Seconds per frame (a whole 4-frame scene, build included, divided by 4; median of `repeats`)
    and projector-pass quality of frame 0, for both ways."""
    spec = bench_spec(rig, inputs, n_objects, lights=lights)
    reference = reference_projector(renderer, spec, reference_samples, cache)
    spec["poses"] = scene_poses()
    results = {}
    for name, way in (("one", one_render_scene), ("three", three_renders_scene)):
        runs = [timed(lambda way=way: way(renderer, spec)) for _ in range(repeats)]
        lit = flood_lit(runs[0][0][1])
        results[f"{name}_s"] = statistics.median(seconds for _, seconds in runs) / len(spec["poses"])
        results[f"{name}_quality"] = statistics.median(
            correlation(projector, reference, lit) for (projector, _), _ in runs
        )
    (_, build) = timed(lambda: renderer.setup(SceneSpec.from_dict(spec)))
    results["setup_s"] = build
    return results


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.render_speed", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument(
        "--sizes", default="640,1216", help="camera widths, comma-separated (default 640,1216)"
    )
    parser.add_argument("--objects", type=int, default=300, help="random objects (default 300)")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per way (default 3)")
    parser.add_argument(
        "--reference-samples",
        type=int,
        default=128,
        help="samples of the projector-only reference render (default 128)",
    )
    parser.add_argument("--no-lights", action="store_true", help="no extra point lights (world only)")
    parser.add_argument("--reference-cache", type=Path, help="folder keeping reference renders between runs")
    args = parser.parse_args(argv)

    from generator.blender.render import SceneRenderer

    rows = []
    with tempfile.TemporaryDirectory(prefix="dotsim-bench-") as tmp, SceneRenderer() as renderer:
        for width in (int(w) for w in args.sizes.split(",")):
            rig = bench_rig(width)
            inputs = write_inputs(rig, Path(tmp))
            r = measure(
                renderer,
                rig,
                inputs,
                args.objects,
                args.repeats,
                args.reference_samples,
                lights=not args.no_lights,
                cache=args.reference_cache,
            )
            rows.append((rig, r))
            print(
                f"{rig.camera.width}x{rig.camera.height}, {args.objects} objects: one render "
                f"{r['one_s']:.2f} s/frame (quality {r['one_quality']:.4f}), three renders "
                f"{r['three_s']:.2f} s/frame (quality {r['three_quality']:.4f}), "
                f"speed-up {r['three_s'] / r['one_s']:.2f}x; scene build {r['setup_s']:.2f} s",
                flush=True,
            )
    print(
        "\nsummary (medians of",
        args.repeats,
        "runs; quality = correlation with a",
        args.reference_samples,
        "sample projector-only render over flood-lit pixels)",
    )
    print(
        f"{'size':>10} {'one s/frame':>12} {'quality':>8} {'three s/frame':>14} {'quality':>8} "
        f"{'speed-up':>9} {'build s':>8}"
    )
    for rig, r in rows:
        print(
            f"{rig.camera.width:>5}x{rig.camera.height:<4} {r['one_s']:>12.2f} {r['one_quality']:>8.4f} "
            f"{r['three_s']:>14.2f} {r['three_quality']:>8.4f} {r['three_s'] / r['one_s']:>8.2f}x "
            f"{r['setup_s']:>8.2f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
