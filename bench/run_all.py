"""Run every benchmark, one after another, each in its own process (they measure memory and time).
    python -m bench.run_all [--only NAME,NAME] [--quick]
--quick passes each benchmark its smallest settings (a smoke run, not figures to report).
Long: the full set takes well over an hour on two cores; figures to report come from full runs.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time

# Module name -> arguments for a quick smoke run.
BENCHMARKS = {
    "pattern_uniqueness": ["--repeats", "1"],
    "read_shards": ["--repeats", "1", "--shards", "1", "--scenes", "1"],
    "seal_cost": ["--scenes", "20", "--scenes-per-shard", "10"],
    "kill_trials": ["--trials", "1", "--during-seal", "1", "--base", "2", "--extra", "2"],
    "generate_stages": ["--sizes", "152", "--repeats", "1", "--compression"],
    "direct_settings": ["--width", "152", "--repeats", "1"],
    "assets_build": ["--repeats", "1", "--no-blender"],
    "render_speed": ["--sizes", "640", "--repeats", "1"],
    "mask_fidelity": ["--scenes", "2", "--width", "160", "--objects", "40", "--reference-scenes", "1",
                      "--reference-samples", "16", "--timing-sizes", "160", "--timing-objects", "40",
                      "--repeats", "1"],
    "second_pass": ["--sizes", "160", "--objects", "40", "--repeats", "1"],
    "stereo_cost": ["--sizes", "128", "--objects", "10", "--repeats", "2"],
    "rgb_cost": ["--sizes", "128", "--objects", "10", "--repeats", "1"],
    "render_objects": ["--repeats", "1"],
    "render_memory": ["--minutes", "1"],
    "trainer_speed": ["--repeats", "1", "--no-published"],
    "trainer_accuracy": ["--minutes", "1"],
    "trainer_ddp": ["--steps", "5"],
    "trainer_gpu": ["--repeats", "3", "--train-steps", "3", "--backbones", "conv"],  # skips without CUDA
    "scene_cost": ["--scales", "0.1", "--scenes", "1"],
    "cluster_overhead": ["--scenes", "2", "--repeats", "1", "--scale", "0.1"],
    "generate_cost": ["--pairs", "1", "--scale", "0.05", "--objects", "5", "--threads", "1"],
    "sensor_fit": ["--scale", "0.2", "--scenes", "1"],
    "real_recording": ["--train-scenes", "1", "--test-scenes", "1", "--workers", "1", "--minutes", "0.1"],
    "audit_probes": ["--only", "config"],  # issue 45's inputs; whole, it renders one tiny scene
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.run_all", description=__doc__.splitlines()[0])
    parser.add_argument("--only", default="", help="comma-separated benchmark names (default: all): "
                        + ", ".join(BENCHMARKS))
    parser.add_argument("--quick", action="store_true", help="smallest settings (smoke run)")
    args = parser.parse_args(argv)
    names = [n for n in args.only.split(",") if n] or list(BENCHMARKS)
    unknown = sorted(set(names) - set(BENCHMARKS))
    if unknown:
        parser.error(f"unknown benchmark(s) {unknown}; allowed: {', '.join(BENCHMARKS)}")
    failed = []
    for name in names:
        command = [sys.executable, "-m", f"bench.{name}"] + (BENCHMARKS[name] if args.quick else [])
        print(f"\n=== bench.{name} ===", flush=True)
        start = time.perf_counter()
        if subprocess.run(command).returncode != 0:
            failed.append(name)
        print(f"=== bench.{name}: {time.perf_counter() - start:.0f} s", flush=True)
    print(f"\n{len(names) - len(failed)} benchmarks ran, {len(failed)} failed"
          + (f": {failed}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
