"""The simulated device's depth engine (dotsim.device_depth) against the frame's render, side by side:
seconds per frame of rendering a frame (engine off) and of the engine on that frame, and their ratio
(the goal: at most 0.15), at the devices' full size: stereo on the realsense_d415 config (1280 x 720,
left against right IR), structured light on the structure_core config (1216 x 896, against the
reference image; the reference is made once per run and timed apart).

    python -m bench.device_depth_cost [--scale 1.0] [--repeats 3] [--out out/device_depth_cost]

Renders one test scene of each config at `--scale` with [device_depth] off into a fresh --out (the
render's seconds per frame: the run's wall time over its four frames, scene building, Cycles,
post-render and writing together), then times each engine on the scene's four frames, `--repeats`
times each (median), with the config's [device_depth] settings (structure_core: its own with
engine = "structured_light"). Run it on a quiet machine; `--scale 0.1` checks that it runs.
"""

from __future__ import annotations

import argparse
import functools
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from dotsim.config_schema import read_toml
from dotsim.configs import config_path, relative_base
from dotsim.device_depth import reference_image_at, stereo_depth, structured_light_depth
from dotsim.frame_source import open_source
from generator.config import config_from_dict
from generator.driver import generate

CASES = (("stereo", "realsense_d415"), ("structured_light", "structure_core"))


def case_config(name: str, scale: float):
    """The built-in config `name` at render scale `scale` with its device depth engine off (the render
    alone)."""
    path = config_path(name)
    data = read_toml(path)
    data.setdefault("rig", {})["scale"] = scale
    data.setdefault("device_depth", {})["engine"] = "off"
    return config_from_dict(data, f"{path} (scale {scale}, device depth off)", base_dir=relative_base(path))


def _stereo(frame: dict, rig, settings, scale: float) -> np.ndarray:
    return stereo_depth(frame["ir"], frame["ir_right"], rig.camera.fx, rig.second_camera_translation[0],
                        settings, scale)


def _structured_light(frame: dict, reference: np.ndarray, rig, settings, scale: float) -> np.ndarray:
    return structured_light_depth(frame["ir"], reference, rig.camera.fx, rig.baseline, settings, scale)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scale", type=float, default=1.0, help="render scale (1.0: the devices' full size)")
    parser.add_argument("--repeats", type=int, default=3, help="timings of the engine per frame (median)")
    parser.add_argument("--out", type=Path, default=Path("out/device_depth_cost"))
    args = parser.parse_args(argv)
    lines = ["| engine | image | render s/frame | engine s/frame | ratio |", "|---|---|---|---|---|"]
    for engine, name in CASES:
        config = case_config(name, args.scale)
        out = args.out / name
        summary = generate(config, out, "test", 1, seed=1)
        print(summary.line())
        if not summary.done:
            raise SystemExit(f"{out}: the scene was already there; its render time is not known: remove "
                             f"the folder and run again")
        render_s = summary.seconds / summary.frames
        source = open_source(out, "test")
        rig = source.rig
        settings = replace(config.device_depth, engine=engine)
        extra = ""
        if engine == "stereo":
            channels = ("ir", "ir_right")
            run = functools.partial(_stereo, rig=rig, settings=settings, scale=args.scale)
        else:
            began = time.perf_counter()
            reference = reference_image_at(source.pattern, rig, settings.reference_distance)
            extra = f" (+ {time.perf_counter() - began:.2f} s once for the reference image)"
            channels = ("ir",)
            run = functools.partial(_structured_light, reference=reference, rig=rig, settings=settings,
                                    scale=args.scale)
        times = []
        for ref in source.frames:
            frame = {k: v.astype(np.float32) for k, v in ref.read(channels).items()}
            for _ in range(args.repeats):
                began = time.perf_counter()
                run(frame)
                times.append(time.perf_counter() - began)
        engine_s = float(np.median(times))
        lines.append(f"| {engine} | {rig.camera.width} x {rig.camera.height} | {render_s:.2f} | "
                     f"{engine_s:.3f}{extra} | {engine_s / render_s:.3f} |")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
