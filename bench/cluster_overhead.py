"""Benchmark: Ray's overhead against local workers on the same scenes, and the time from submit to
the first scene written with Ray and with Slurm.

    python -m bench.cluster_overhead [--scenes 16] [--workers 2] [--repeats 2] [--scale 0.25]
                                     [--config dotsim/configs/structure_core.toml] [--no-slurm]

(the default config draws meshes from the asset cache: build it once with `make assets-train`)

Each repeat renders the same scenes (the config at --scale, one render thread per worker, same
seed and range) into fresh folders, once with `--workers W` local processes and once with
`--ray local` on a cluster of W CPUs started beforehand (a cluster outlives runs; its start-up is
printed separately), alternating which goes first. Throughput is scenes per hour of wall time
from the call to the sealed dataset; Ray's overhead is (local rate / Ray rate - 1), median over
repeats (goal: at most 5%). Submit to first scene: from the call (Ray) or from `dotsim generate
--slurm` (Slurm: a one-node cluster of its own, generator.engines.one_node_slurm, needs root and
slurm-wlm; dotsim/configs/tiny.toml, two array tasks) until the first scene folder is complete.
Run on a quiet machine: other load on the cores changes both rates.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import threading
import time
from pathlib import Path

from bench.scene_cost import config_at
from dotsim import dataset
from generator.config import load_config
from generator.driver import generate, run
from generator.engines.ray_cluster import RayExecutor
from generator.run_request import RunRequest

SLURM_CONFIG = Path("dotsim/configs/tiny.toml")


def first_scene_clock(out: Path, began: float) -> dict:
    """Start a thread that records seconds from `began` until `out` holds a complete scene."""
    seen: dict = {}

    def watch():
        while "first" not in seen and not seen.get("stop"):
            if dataset.complete_scenes(out):
                seen["first"] = time.perf_counter() - began
            time.sleep(0.02)

    seen["thread"] = threading.Thread(target=watch, daemon=True)
    seen["thread"].start()
    return seen


def timed_run(config, out: Path, scenes: int, workers: int, executor=None) -> tuple[float, float]:
    """(wall seconds to a sealed dataset, seconds to the first complete scene)."""
    began = time.perf_counter()
    clock = first_scene_clock(out, began)
    summary = generate(config, out, "train", scenes, workers=workers, progress=False, executor=executor)
    seconds = time.perf_counter() - began
    clock["stop"] = True
    clock["thread"].join()
    assert summary.done == scenes and not summary.failed, summary.line()
    return seconds, clock.get("first", seconds)


def slurm_first_scene(config_path: Path, scenes: int, tmp: Path) -> tuple[float, float]:
    """(submit to first scene, submit to sealed) on a one-node Slurm started here."""
    from generator.engines.one_node_slurm import one_node_slurm, wait_for_jobs
    from generator.engines.slurm import SlurmExecutor, SlurmOptions

    with one_node_slurm(tmp / "slurm") as env:
        os.environ["SLURM_CONF"] = env["SLURM_CONF"]  # for the sbatch that SlurmExecutor runs
        out = tmp / "slurm-out"
        began = time.perf_counter()
        executor = SlurmExecutor(SlurmOptions(scenes_per_task=max(1, -(-scenes // 2))))
        said = run(RunRequest(load_config(config_path), out, "train", scenes, executor=executor)).line()
        clock = first_scene_clock(out, began)
        wait_for_jobs(said.split("squeue -j ")[1].split("`")[0], env, timeout_s=3600)
        sealed = time.perf_counter() - began
        clock["stop"] = True
        clock["thread"].join()
        if not (out / dataset.INDEX_FILE).exists():
            raise RuntimeError(f"the Slurm run did not seal {out}; logs in {out / 'slurm'}")
        return clock.get("first", sealed), sealed


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.cluster_overhead",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=Path("dotsim/configs/structure_core.toml"))
    parser.add_argument("--scale", type=float, default=0.25, help="rig scale (default 0.25: 304 x 224)")
    parser.add_argument("--scenes", type=int, default=16)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--no-slurm", action="store_true",
                        help="skip the Slurm submit-to-first-scene timing")
    args = parser.parse_args(argv)
    config = config_at(args.config, args.scale)
    threads = 1
    with tempfile.TemporaryDirectory(prefix="dotsim-bench-cluster-") as tmp:
        tmp = Path(tmp)
        ray_executor = RayExecutor("local", local_workers=args.workers)
        began = time.perf_counter()
        ray_executor.connect(threads)
        print(f"ray local cluster of {args.workers * threads} CPUs started in "
              f"{time.perf_counter() - began:.1f} s")
        rates: dict[str, list[float]] = {"local": [], "ray": []}
        firsts: dict[str, list[float]] = {"local": [], "ray": []}
        try:
            for repeat in range(args.repeats):
                order = ("local", "ray") if repeat % 2 == 0 else ("ray", "local")
                for name in order:
                    seconds, first = timed_run(config, tmp / f"{name}{repeat}", args.scenes, args.workers,
                                               ray_executor if name == "ray" else None)
                    rates[name].append(3600 * args.scenes / seconds)
                    firsts[name].append(first)
                    print(f"repeat {repeat} {name:5s}: {args.scenes} scenes in {seconds:.1f} s "
                          f"({rates[name][-1]:.0f} scenes/h), first scene after {first:.1f} s", flush=True)
        finally:
            ray_executor.close()
        overheads = [lo / ra - 1 for lo, ra in zip(rates["local"], rates["ray"], strict=True)]
        overhead = 100 * statistics.median(overheads)
        print(f"local {statistics.median(rates['local']):.0f} scenes/h, "
              f"ray {statistics.median(rates['ray']):.0f} scenes/h with {args.workers} workers: "
              f"ray overhead {overhead:+.1f}% "
              f"(goal <= 5%); first scene: local {statistics.median(firsts['local']):.1f} s, "
              f"ray {statistics.median(firsts['ray']):.1f} s after the call")
        if not args.no_slurm:
            first, sealed = slurm_first_scene(SLURM_CONFIG.resolve(), args.scenes, tmp)
            print(f"slurm (one node, {args.scenes} scenes in 2 array tasks): first scene {first:.1f} s after "
                  f"submitting, sealed after {sealed:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
