"""Benchmark: Cycles settings tried on the direct render (the spot alone, no bounces), time and pixels.

    python -m bench.direct_settings [--width 608] [--repeats 3] [--scene 0]

Renders scene --scene of the built-in structure_core config (built-in primitives; scene 1 has two
extra lights, so the generator takes the direct render for it; scene 0 has none, and its direct
render is run here all the same) at --width, then the scene's direct renders (one per pose,
as SceneRenderer.render_poses runs them) once per variant, the variants taking turns, and prints
per variant the median wall and CPU seconds per frame and the largest difference of its R and G
(projector_direct, flood_direct) from the renderer's own direct render. Variants, each a change on
top of the renderer's direct render (which switches the light passes off, docs/RENDERING.md):
light passes on (as before issue 26), the light tree off, 256 px tiles, the Z pass off.
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

from dotsim.configs import builtin_path
from generator.blender.frame_recipe import DIRECT_LIGHT_RENDER, LIGHT_PASSES
from generator.blender.render import SceneRenderer
from generator.config import config_from_dict
from generator.engines.steps import prepare_run
from generator.run_request import RunRequest
from generator.sample_scene import sample_scene_spec

FULL_WIDTH = 1216


def _set(target, name: str, value):
    """Set an attribute for the duration of a with block."""
    @contextlib.contextmanager
    def change():
        saved = getattr(target, name)
        setattr(target, name, value)
        try:
            yield
        finally:
            setattr(target, name, saved)
    return change


def variants(renderer: SceneRenderer) -> dict:
    layer, cycles = renderer.scene.view_layers[0], renderer.scene.cycles

    @contextlib.contextmanager
    def light_passes_on():
        renderer._set_light_passes(frozenset(LIGHT_PASSES))
        yield  # the renderer sets its passes again after the direct renders

    return {"as the renderer does": contextlib.nullcontext, "light passes on": light_passes_on,
            "light tree off": _set(cycles, "use_light_tree", False),
            "256 px tiles": _set(cycles, "tile_size", 256), "Z pass off": _set(layer, "use_pass_z", False)}


def direct_renders(renderer: SceneRenderer, poses, variant) -> tuple[list[np.ndarray], float, float]:
    """R and G of the direct render of every pose, and the wall and CPU seconds per frame."""
    images = []
    with renderer._set_for(DIRECT_LIGHT_RENDER), variant():
        wall, cpu = time.perf_counter(), time.process_time()
        for pose in poses:
            renderer.place_rig(pose)
            channels = renderer._render_channels()
            images += [channels["R"].copy(), channels["G"].copy()]
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return images, wall / len(poses), cpu / len(poses)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.direct_settings",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=608, help="IR width (default 608)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scene", type=int, default=0)
    args = parser.parse_args(argv)
    config_path = builtin_path("structure_core")
    data = tomllib.loads(config_path.read_text())
    data["rig"]["scale"] = args.width / FULL_WIDTH
    data["assets"] = {"source": "primitives"}
    config = config_from_dict(data, source=str(config_path), base_dir=config_path.parent)
    with tempfile.TemporaryDirectory(prefix="dotsim-direct-") as tmp, SceneRenderer() as renderer:
        job = prepare_run(RunRequest(config, Path(tmp) / "d", "train", 1))
        spec = sample_scene_spec(config, args.scene, 0, "train", job.resources)
        poses = renderer.setup(spec)
        # The path-traced renders come first, as in render_poses.
        renderer._render_through(renderer.recipe.renders[0], poses, [{} for _ in poses])
        ways = variants(renderer)
        reference = direct_renders(renderer, poses, ways["as the renderer does"])[0]
        times: dict[str, list[tuple[float, float]]] = {name: [] for name in ways}
        differences = dict.fromkeys(ways, 0.0)
        for _ in range(args.repeats):
            for name, variant in ways.items():
                images, wall, cpu = direct_renders(renderer, poses, variant)
                times[name].append((wall, cpu))
                largest = max(float(np.max(np.abs(a - b))) for a, b in zip(images, reference, strict=True))
                differences[name] = max(differences[name], largest)
    print(f"direct render of scene {args.scene} ({len(spec.objects)} objects, {len(spec.lights)} extra "
          f"lights) at {args.width} px, per frame, medians of {args.repeats}")
    print(f"{'variant':24}{'wall s':>9}{'CPU s':>9}{'max |difference|':>18}")
    for name, runs in times.items():
        wall, cpu = (statistics.median(run[k] for run in runs) for k in (0, 1))
        print(f"{name:24}{wall:>9.3f}{cpu:>9.3f}{differences[name]:>18.2e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
