"""Benchmark: what a whole `dotsim generate` process costs, this checkout against another revision,
side by side: start-up, input checks, pattern and seal around the render.

    python -m bench.generate_cost [--before b1d787e] [--pairs 5] [--scenes 1] [--scale 0.5] \
        [--objects 300] [--threads 2]

Each side runs `dotsim generate` into a new folder, as a process of its own with this interpreter
(the other revision unpacked by bench.generate_stages.unpack, its entry module chosen by
dotsim_command), on the same config: Structure Core at --scale (0.5: 608 x 448), --objects built-in
primitives (no asset cache), no extra lights, [render] threads --threads, one worker, seed 0. The
sides take turns, the first of each pair alternating, --pairs times. Per run it measures the wall
seconds of the whole process, the peak RSS (VmHWM, read while they run) of the main process and of
its largest descendant (the render worker), and the worker's own seconds per scene (the summary
line). It prints the
median of each per side and after / before, and exits 1 when a run fails. The worker's seconds
should agree between the sides: what differs outside them is the cost the issue asks about.
Run it on an idle machine (timings under load mean nothing).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from bench.generate_stages import dotsim_command, unpack

REPO = Path(__file__).resolve().parents[1]
WORKER_SECONDS = re.compile(r"([\d.]+) s of one worker's time each")
CONFIG = """[rig]
preset = "structure_core"
scale = {scale}

[render]
samples = 1
threads = {threads}

[scene]
object_count = [{objects}, {objects}]

[lighting]
extra_lights = [0, 0]

[assets]
source = "primitives"
"""


def _peak_kib(pid: int) -> int | None:
    """The process's peak RSS so far (VmHWM, KiB), None once it is gone."""
    try:
        with open(f"/proc/{pid}/status") as status:
            return next(int(line.split()[1]) for line in status if line.startswith("VmHWM:"))
    except (OSError, StopIteration, ValueError):
        return None


def _children(pid: int) -> list[int]:
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as listing:
            return [int(child) for child in listing.read().split()]
    except OSError:
        return []


def measure(command: list[str], cwd: str, pythonpath: str, every_s: float = 0.05) -> dict:
    """Run `command` and measure it: wall seconds, the peak RSS (KiB) of its main process and of the
    largest of its descendants (the render worker), and its output. Peaks are VmHWM, read every
    `every_s` seconds while the processes live (a peak never falls, so the last reading of each is
    its peak up to then; os.wait4's figure would fold the waited-for children into the main one)."""
    began = time.perf_counter()
    proc = subprocess.Popen(command, cwd=cwd, env={**os.environ, "PYTHONPATH": pythonpath},
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    peaks: dict[int, int] = {}
    reader = threading.Thread(target=lambda: peaks.setdefault(-1, proc.stdout.read()), daemon=True)
    reader.start()
    while proc.poll() is None:
        pending, seen = [proc.pid], set()
        while pending:
            pid = pending.pop()
            seen.add(pid)
            if (kib := _peak_kib(pid)) is not None:
                peaks[pid] = max(peaks.get(pid, 0), kib)
            pending += [child for child in _children(pid) if child not in seen]
        time.sleep(every_s)
    wall = time.perf_counter() - began
    reader.join()
    output = peaks.pop(-1)
    others = [kib for pid, kib in peaks.items() if pid != proc.pid]
    return {"wall": wall, "code": proc.returncode, "main_kib": peaks.get(proc.pid, 0),
            "worker_kib": max(others, default=0), "output": output}


def run_once(tree: Path, config: Path, out: Path, scenes: int) -> dict:
    """`dotsim generate` with the code of checkout `tree`, measured by a process of its own (so the
    measuring never shares this one's threads or memory)."""
    command = [*dotsim_command(tree), "generate", "--config", str(config), "--out", str(out), "--split",
               "train", "--scenes", str(scenes), "--workers", "1", "--no-progress"]
    done = subprocess.run([sys.executable, "-m", "bench.generate_cost", "--measure", str(tree),
                           json.dumps(command)], cwd=REPO, capture_output=True, text=True, check=True)
    result = json.loads(done.stdout)
    if result["code"] != 0:
        raise RuntimeError(f"{' '.join(command)} failed ({result['code']}):\n{result['output'][-3000:]}")
    worker = WORKER_SECONDS.search(result["output"])
    return {"wall s": result["wall"], "main peak MiB": result["main_kib"] / 1024,
            "worker peak MiB": result["worker_kib"] / 1024,
            "worker s/scene": float(worker.group(1)) if worker else float("nan")}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", default="b1d787e",
                        help="git revision to compare with (default b1d787e, issue 37's reference)")
    parser.add_argument("--pairs", type=int, default=5, help="runs per side, taking turns (default 5)")
    parser.add_argument("--scenes", type=int, default=1, help="scenes per run (default 1)")
    parser.add_argument("--scale", type=float, default=0.5, help="Structure Core scale (default 0.5)")
    parser.add_argument("--objects", type=int, default=300, help="primitives per scene (default 300)")
    parser.add_argument("--threads", type=int, default=2, help="[render] threads (default 2)")
    parser.add_argument("--measure", nargs=2, metavar=("TREE", "COMMAND_JSON"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.measure:  # the measuring process of one run (run_once)
        tree, command = args.measure
        print(json.dumps(measure(json.loads(command), tree, tree)))
        return 0
    with tempfile.TemporaryDirectory(prefix="dotsim-generate-cost-") as tmp:
        tmp = Path(tmp)
        sides = {"before": unpack(args.before, tmp), "after": REPO}
        config = tmp / "cost.toml"
        config.write_text(CONFIG.format(scale=args.scale, threads=args.threads, objects=args.objects))
        runs: dict[str, list[dict]] = {side: [] for side in sides}
        for pair in range(args.pairs):
            order = list(sides) if pair % 2 == 0 else list(sides)[::-1]
            for side in order:
                measured = run_once(sides[side], config, tmp / f"{side}_{pair}", args.scenes)
                runs[side].append(measured)
                print(f"pair {pair} {side:6}: " + ", ".join(f"{k} {v:.2f}" for k, v in measured.items()),
                      flush=True)
    print(f"\nmedians of {args.pairs} runs per side, {args.scenes} scene(s), scale {args.scale}, "
          f"{args.objects} primitives, {args.threads} threads ({args.before} -> this checkout):")
    for key in runs["after"][0]:
        before, after = (statistics.median(run[key] for run in runs[side]) for side in ("before", "after"))
        print(f"  {key:16} {before:8.2f} -> {after:8.2f}  ({after / before:.3f}x)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
