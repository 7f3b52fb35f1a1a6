"""The ambient-to-projector ratio each built-in config renders: per frame, the ambient light over the
projector's light where the projector reaches directly (generator.post_render.ambient_projector_ratio,
fit-sensor's ambient / projector statistic), from the raw passes of the scenes' renders, before the
sensor model; its median and the 10th to 90th percentile over the frames of --scenes scenes.

    python -m bench.ambient_ratio [--width 64] [--scenes 4] [--configs default,kinect,...]

Built-in primitives instead of an asset cache (the lighting is the config's), 1 Cycles sample, the
configs at [rig] scale width / their camera width. For comparison: the vendored Kinect v1 frame gives
15 (the one-frame estimate of `dotsim capture compare`). [lighting] ambient_ratio, when set, scales a
scene to its target after this (docs/CAPTURE.md "Rooms lit as real rooms are"); this bench measures the
configs as they are.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

CONFIGS = ("default", "structure_core", "kinect", "realsense_d415", "realsense_d435", "tiny",
           "bench_accuracy", "table2")


def frame_ratios(name: str, width: int, scenes: int, folder: Path) -> list[float]:
    """The ambient / projector ratio of every frame of `scenes` scenes of config `name`."""
    from generator.blender.render import SceneRenderer
    from generator.config import config_from_dict, load_config
    from generator.engines.steps import prepare_run
    from generator.post_render import ambient_projector_ratio
    from generator.run_request import RunRequest
    from generator.sample_scene import build_rig, sample_scene_spec

    base = load_config(name)
    data = base.to_dict()
    data.pop("source")
    scale = base.rig.scale * width / build_rig(base).camera.width
    data["rig"] = {**data["rig"], "scale": scale}
    data["render"] = {**data["render"], "samples": 1}
    data["assets"] = {"source": "primitives"}
    config = config_from_dict(data, source=f"{name} at {width} px")
    job = prepare_run(RunRequest(config, folder / name, "train", scenes))
    renderer = SceneRenderer()
    ratios = []
    try:
        for index in range(scenes):
            spec = sample_scene_spec(config, index, 0, "train", job.resources)
            for raw in renderer.render(spec):
                ratio = ambient_projector_ratio(raw["ambient"], raw["projector"], raw["flood_direct"] > 0)
                if ratio is not None:
                    ratios.append(ratio)
    finally:
        renderer.close()
    return ratios


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.ambient_ratio",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--width", type=int, default=64, help="camera width of the renders, px (default 64)")
    parser.add_argument("--scenes", type=int, default=4, help="scenes per config (default 4)")
    parser.add_argument("--configs", default=",".join(CONFIGS), help="built-in configs, comma-separated")
    args = parser.parse_args(argv)
    print(f"{'config':16}{'frames':>8}{'median':>10}{'p10':>10}{'p90':>10}")
    with tempfile.TemporaryDirectory(prefix="dotsim-ambient-ratio-") as tmp:
        for name in args.configs.split(","):
            ratios = frame_ratios(name, args.width, args.scenes, Path(tmp))
            p10, median, p90 = np.percentile(ratios, [10, 50, 90]) if ratios else (np.nan,) * 3
            print(f"{name:16}{len(ratios):>8}{median:>10.3g}{p10:>10.3g}{p90:>10.3g}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
