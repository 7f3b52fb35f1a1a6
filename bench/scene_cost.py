"""Benchmark: what one scene costs at each resolution, on one core: seconds, MB on disk, files.

    python -m bench.scene_cost [--scales 0.25,0.5,1.0] [--scenes 2] [--config structure_core]

Renders --scenes scenes of the config at each rig scale with one render worker of one thread
([render] threads = 1), so seconds per scene are per core: a node with C cores and enough memory
runs C such workers (docs/SCALE.md turns this into scenes per node-hour). Prints, per scale, the
worker's seconds per scene (render to written, Blender's start-up excluded), the scene folder's
size in MB, its file count (what a shared filesystem must create per scene), the peak resident
memory of a render worker and how many scenes have extra lights (those take two Cycles renders
per frame, the others one: docs/RENDERING.md).
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import tomllib
from pathlib import Path

from dotsim import dataset
from generator.config import config_from_dict
from generator.driver import generate


def config_at(config_path: Path, scale: float, threads: int = 1):
    """The config of a file with its rig scale and render threads replaced."""
    data = tomllib.loads(config_path.read_text())
    data.setdefault("rig", {})["scale"] = scale
    data.setdefault("render", {})["threads"] = threads
    return config_from_dict(data, source=f"{config_path} at scale {scale}, {threads} thread(s)",
                            base_dir=config_path.resolve().parent)


def scene_cost(config_path: Path, scale: float, scenes: int) -> dict:
    config = config_at(config_path, scale)
    with tempfile.TemporaryDirectory(prefix="dotsim-scene-cost-") as tmp:
        out = Path(tmp) / "d"
        summary = generate(config, out, "train", scenes, progress=False)
        dirs = [path for _, path in dataset.complete_scenes(out)]
        files = [p for d in dirs for p in d.iterdir() if p.is_file()]
        metas = [dataset.read_scene_meta(d, verify=False) for d in dirs]
        height, width = dataset.camera_size(metas[0])
        return {"scale": scale, "size": f"{width} x {height}",
                "s_per_scene": summary.worker_seconds / summary.done,
                "mb_per_scene": sum(p.stat().st_size for p in files) / len(dirs) / 1e6,
                "files_per_scene": len(files) / len(dirs),
                "with_lights": f"{sum(bool(meta['lights']) for meta in metas)} of {len(dirs)}",
                # Largest resident memory of any worker process so far (scales run in rising order).
                "worker_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.scene_cost", description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=Path("dotsim/configs/structure_core.toml"))
    parser.add_argument("--scales", default="0.25,0.5,1.0", help="rig scales, comma-separated")
    parser.add_argument("--scenes", type=int, default=2, help="scenes per scale (default 2)")
    args = parser.parse_args(argv)
    print("| scale | IR size | s per scene, one core | scenes per core-hour | MB per scene | "
          "files per scene | worker peak MB | scenes with extra lights |")
    print("|---|---|---|---|---|---|---|---|")
    for scale in (float(s) for s in args.scales.split(",")):
        r = scene_cost(args.config, scale, args.scenes)
        print(f"| {r['scale']} | {r['size']} | {r['s_per_scene']:.1f} | {3600 / r['s_per_scene']:.0f} | "
              f"{r['mb_per_scene']:.2f} | {r['files_per_scene']:.0f} | {r['worker_mb']:.0f} | "
              f"{r['with_lights']} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
