"""Visibility-mask leak, missing dots ("pepper") and render time: the one-render way ("old",
generator.blender.frame_recipe.WITHOUT_DIRECT_LIGHT, mask from flood - ambient) against the direct
light's two ways ("separate": rendered apart, the default; "shared": from the path-traced render,
[render] direct_light), both with the mask dotsim.masks.direct_visibility_mask, side by side on
the same scenes in one run.

    python -m bench.mask_fidelity [--scenes 20] [--width 320] [--objects 150] [--reference-scenes 3]
        [--timing-sizes 640,1216] [--timing-objects 300] [--repeats 3] [--no-timing] [--no-fidelity]

Fidelity (frame 0 of each scene): random clutter before a wall (bench.render_speed's scene) with
1, 2 or 3 extra point lights (20-100 W, random places), 1 sample. Judged by dotsim.oracle's
projector_lighting (a shadow test from the projector's viewpoint, independent of Cycles), leaving
out the 2 px band at depth edges (dotsim.masks.edge_mask) and 2 px at shadow borders:
- leak: share of cast-shadow pixels (facing the projector, inside its image) marked visible;
- no dot: share of visible pixels without a dot that the sensor shows above the margin within
  5 x 5 px (noise-free dots: exposure gain x blurred projector pass, against margin x the noise
  sigma at the ambient level, dotsim.sensor.model.SensorModel's exposure and noise);
- recall: share of directly lit pixels (cos > 0.2, nearer than 4 m) with such a dot marked visible;
- pepper: share of directly lit pixels whose flood pass is below 5% of what the oracle's
  cos / r^2 predicts (scaled by the scene's median ratio, which absorbs power and albedo);
- ambient: correlation of the ambient pass with a --reference-samples render, first
  --reference-scenes scenes.
Timing: bench.render_speed's scene (N objects) with two 50 W lights and without extra lights (both
direct-light ways then take it from the path-traced render's passes: one render), a whole scene
(build + 4 frames) / 4, the three ways alternating, median of --repeats, wall time and CPU time of
the process (all its threads). Wall times on a loaded machine are not figures; CPU times are
steadier there.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from bench.render_speed import bench_rig, bench_spec, correlation, scene_poses, write_inputs
from dotsim.masks import edge_mask, visibility_mask
from dotsim.oracle import expected_pattern_image, projector_lighting
from dotsim.sensor.model import SensorModel, SensorStreams
from generator.blender.frame_recipe import WITHOUT_DIRECT_LIGHT
from generator.config import config_from_dict
from generator.post_render import make_frame
from generator.scene_spec import SceneSpec

# name: (render.direct_light, the frame recipe: None for the spec's own)
WAYS = {"old": ("separate", WITHOUT_DIRECT_LIGHT), "separate": ("separate", None), "shared": ("shared", None)}


def way_spec(spec: dict, name: str) -> SceneSpec:
    """`spec` as the way `name` renders it (render it with the recipe WAYS gives, too)."""
    return SceneSpec.from_dict(dict(spec, render=dict(spec["render"], direct_light=WAYS[name][0])))


def random_lights(seed: int) -> list[dict]:
    """1, 2 or 3 (by seed) extra point lights, 20-100 W, somewhere in the room before the wall."""
    rng = np.random.default_rng(1000 + seed)
    return [
        {
            "type": "POINT",
            "location": [float(rng.uniform(low, high)) for low, high in ((-2, 2), (-1.5, 0.5), (0.5, 4))],
            "power": float(rng.uniform(20, 100)),
            "radius": float(rng.uniform(0.02, 0.3)),
        }
        for _ in range(seed % 3 + 1)
    ]


def _erode(mask: np.ndarray, pixels: int) -> np.ndarray:
    kernel = np.ones((2 * pixels + 1,) * 2, np.uint8)
    return cv2.erode(mask.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0


def judged_regions(depth: np.ndarray, rig) -> tuple[np.ndarray, np.ndarray]:
    """(directly lit, cast shadow) by the oracle, away from depth edges and shadow borders."""
    cosine, inside, shadowed = projector_lighting(depth, rig)
    keep = np.isfinite(depth) & ~edge_mask(depth)
    with np.errstate(invalid="ignore"):
        lit = inside & ~shadowed & (cosine > 0.2) & (depth < 4.0)
        shadow = shadowed & (cosine > 0)
    return _erode(lit, 2) & keep, _erode(shadow, 2) & keep


def sensor_dots(raw: dict, sensor: SensorModel, margin: float) -> np.ndarray:
    """Pixels with a dot the sensor shows above the noise margin within 5 x 5 px (noise-free)."""
    signal = raw["ambient"] + raw["projector"]
    gain = sensor.exposure_gain(signal)
    dots = gain * raw["projector"].astype(np.float64)
    dots = cv2.GaussianBlur(dots, (0, 0), sensor.blur_px)
    nearby = cv2.dilate(dots, np.ones((5, 5), np.uint8))
    return nearby > margin * sensor.sigma(gain * raw["ambient"])


def fidelity(raw: dict, visible: np.ndarray, lit: np.ndarray, shadow: np.ndarray, oracle_flood: np.ndarray,
             config) -> dict:
    sensor = SensorModel(config.sensor.at_scale(config.rig.scale))
    dotted = sensor_dots(raw, sensor, config.masks.visibility_margin)
    ratio = raw["flood"][lit] / oracle_flood[lit]
    return {
        "leak": float(visible[shadow].mean()),
        "no_dot": float((visible & ~dotted).sum() / max(visible.sum(), 1)),
        "recall": float(visible[lit & dotted].mean()),
        "pepper": float(np.mean(ratio < 0.05 * np.median(ratio))),
    }


def run_fidelity(renderer, args, folder: Path) -> dict[str, list[dict]]:
    from tqdm import tqdm

    rig = bench_rig(args.width)
    inputs = write_inputs(rig, folder)
    config = config_from_dict({"rig": {"scale": args.width / 1216}})
    results = {name: [] for name in WAYS}
    for seed in tqdm(range(args.scenes), desc="fidelity scenes"):
        spec = bench_spec(rig, inputs, args.objects, seed=seed)
        spec["lights"] = random_lights(seed)
        raws = {}
        for name, (_, recipe) in WAYS.items():
            raws[name] = renderer.render(way_spec(spec, name), recipe)[0]
        depth = raws["separate"]["depth"]
        lit, shadow = judged_regions(depth, rig)
        ones = np.ones((rig.projector.height, rig.projector.width))
        oracle_flood = expected_pattern_image(depth, rig, ones, supersample=1)
        old = raws["old"]
        masks = {name: make_frame(raws[name], way_spec(spec, name),
                                  [SensorStreams(np.random.default_rng(seed))])["visibility"] > 0
                 for name in WAYS if name != "old"}
        masks["old"] = visibility_mask(old["ambient"], old["ambient"] + old["flood"], 0.05, depth=depth)
        reference = None
        if seed < args.reference_scenes:
            many = dict(spec, render=dict(spec["render"], samples=args.reference_samples))
            reference = renderer.render(SceneSpec.from_dict(many), WITHOUT_DIRECT_LIGHT)[0]
        for name in WAYS:
            row = fidelity(raws[name], masks[name], lit, shadow, oracle_flood, config)
            if reference is not None:
                row["ambient"] = correlation(raws[name]["ambient"], reference["ambient"], np.isfinite(depth))
            results[name].append(row)
    return results


def _lights_label(lights: bool) -> str:
    return "two extra lights" if lights else "no extra light"


def run_timing(renderer, args, folder: Path) -> dict[tuple[int, bool], dict[str, float]]:
    """Per (width, extra lights or none): median wall and CPU seconds per frame of each way. CPU
    time (all threads of this process) is the steadier figure on a shared machine, where other work
    stretches wall time."""
    out = {}
    for width, lights in ((int(w), lights) for w in args.timing_sizes.split(",") for lights in (True, False)):
        rig = bench_rig(width)
        spec = bench_spec(rig, write_inputs(rig, folder), args.timing_objects, lights=lights)
        spec["poses"] = scene_poses()
        specs = {name: way_spec(spec, name) for name in WAYS}
        runs = {(name, clock): [] for name in WAYS for clock in ("wall", "cpu")}
        for repeat in range(args.repeats):
            order = list(WAYS) if repeat % 2 == 0 else list(WAYS)[::-1]
            for name in order:
                wall, cpu = time.perf_counter(), time.process_time()
                renderer.render(specs[name], WAYS[name][1])
                runs[name, "wall"].append((time.perf_counter() - wall) / len(specs[name].poses))
                runs[name, "cpu"].append((time.process_time() - cpu) / len(specs[name].poses))
        out[width, lights] = {f"{name}_{clock}": statistics.median(values)
                              for (name, clock), values in runs.items()}
        print(f"{rig.camera.width}x{rig.camera.height} {_lights_label(lights)} s/frame per run: "
              + ", ".join(f"{name} {clock} " + " ".join(f"{v:.2f}" for v in values)
                          for (name, clock), values in runs.items()), flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.mask_fidelity",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=20, help="fidelity scenes (default 20)")
    parser.add_argument("--width", type=int, default=320, help="fidelity camera width (default 320)")
    parser.add_argument("--objects", type=int, default=150, help="objects per fidelity scene (default 150)")
    parser.add_argument("--reference-scenes", type=int, default=3,
                        help="scenes whose ambient is compared with a reference render (default 3)")
    parser.add_argument("--reference-samples", type=int, default=128, help="reference samples (default 128)")
    parser.add_argument("--timing-sizes", default="640,1216", help="timed camera widths (default 640,1216)")
    parser.add_argument("--timing-objects", type=int, default=300,
                        help="objects in the timed scene (default 300)")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per way and size (default 3)")
    parser.add_argument("--no-timing", action="store_true", help="fidelity only")
    parser.add_argument("--no-fidelity", action="store_true", help="timing only")
    args = parser.parse_args(argv)

    from generator.blender.render import SceneRenderer

    with tempfile.TemporaryDirectory(prefix="dotsim-bench-") as tmp, SceneRenderer() as renderer:
        results = {} if args.no_fidelity else run_fidelity(renderer, args, Path(tmp))
        timing = {} if args.no_timing else run_timing(renderer, args, Path(tmp))
    if results:
        print(f"\nfidelity, {args.scenes} scenes at width {args.width} "
              "(mean over scenes; median in brackets)")
        print(f"{'way':>8} {'leak':>14} {'no dot':>14} {'recall':>14} {'pepper':>14} {'ambient corr':>14}")
        for name, rows in results.items():
            cells = []
            for key in ("leak", "no_dot", "recall", "pepper", "ambient"):
                values = [row[key] for row in rows if key in row]
                percent = 1 if key == "ambient" else 100
                cells.append(f"{percent * np.mean(values):6.2f} ({percent * np.median(values):5.2f})"
                             if values else "-")
            print(f"{name:>8} " + " ".join(f"{cell:>14}" for cell in cells))
        print("(leak, no dot, recall, pepper in %; ambient as a correlation)")
    for (width, lights), seconds in timing.items():
        for clock in ("wall", "cpu"):
            old = seconds[f"old_{clock}"]
            print(f"{clock} time per frame at width {width}, {_lights_label(lights)} (medians of "
                  f"{args.repeats}): old {old:.2f} s, " + ", ".join(
                      f"{name} {seconds[f'{name}_{clock}']:.2f} s ({seconds[f'{name}_{clock}'] / old:.2f}x)"
                      for name in WAYS if name != "old"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
