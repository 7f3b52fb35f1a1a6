"""Reliability trials: kill -9 while extending a sealed dataset, then rerun; orphaned processes;
a Ray worker killed mid-scene; and a damaged scene.

    python -m bench.kill_trials --trials 16 --during-seal 4 --ray-trials 2 --out /tmp/kill_trials

1. Renders N scenes (--base, the built-in tiny config, sealed) and, once, N + M scenes (--extra) as the
   reference. Each trial copies the sealed N-scene dataset, starts `dotsim generate --scenes N+M
   --workers W` (--workers, default 2) and kills its main process alone with SIGKILL (as `kill -9
   PID` does, not its process group) at a random moment (uniform over the time a whole extension
   takes; --during-seal trials wait for the last scene folder and kill 0-300 ms later, inside or
   around the seal; a run that ended before its moment is started again with half the delay, up to
   KILL_ATTEMPTS times). Just before the kill it notes every process below the main one (workers,
   the resource tracker) and counts those still running 10 s after the kill: the orphans. It
   records what the kill left (complete scenes, scenes index.json lists, whether
   open_dataset(verify=True) passes), reruns the same command to completion, and checks: exit
   status 0, open_dataset(verify=True) lists all N + M scenes, every frame byte-identical to the
   reference, no `.tmp-` leftovers, `dotsim verify` clean, no orphan.
2. --ray-trials: the same extension with `--ray local`; once a scene is half-written, one Ray
   worker process rendering a task is killed with SIGKILL. Ray retries the task; the run must end
   with exit status 0 and the same checks, and no process of the run (raylet, agents, workers)
   may be running 10 s after it ended.
3. Damaged scene: a frame deleted from a complete scene; the rerun must redo it byte-identically.

Prints one line per trial and a summary with the orphan count. The commands run with the Python
that runs this module, from --code (default: this repository), so an older checkout can be tried
the same way.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

from bench.generate_stages import dotsim_command
from dotsim.process_lifetime import process_status, process_tree

REPO = Path(__file__).resolve().parents[1]
CHECK = """
import json, sys
from dotsim.dataset import open_dataset
try:
    data = open_dataset(sys.argv[1], verify=True)
    print(json.dumps({"ok": True, "scenes": [s.scene_index for s in data.scenes]}))
except Exception as error:
    print(json.dumps({"ok": False, "error": f"{type(error).__name__}: {error}"}))
"""


ORPHAN_WAIT_S = 10.0
KILL_ATTEMPTS = 4


def generate(code: Path, out: Path, scenes: int, *extra: str, **popen) -> subprocess.Popen:
    config = REPO / "dotsim" / "configs" / "tiny.toml"
    command = [*dotsim_command(code), "generate", "--config", str(config), "--out", str(out),
               "--split", "train", "--scenes", str(scenes), "--seed", "3", "--no-progress", *extra]
    return subprocess.Popen(command, cwd=code, env={**os.environ, "PYTHONPATH": str(code)},
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, **popen)


def run(code: Path, out: Path, scenes: int, *extra: str) -> tuple[int, str]:
    proc = generate(code, out, scenes, *extra)
    text, _ = proc.communicate()
    return proc.returncode, text.strip().splitlines()[-1] if text.strip() else ""


def orphans(processes: dict[int, int], wait_s: float = ORPHAN_WAIT_S) -> int:
    """How many of `processes` (pid -> start time) are still running after up to wait_s seconds."""
    deadline = time.monotonic() + wait_s
    while True:
        left = [pid for pid, start in processes.items() if (process_status(pid) or (0, None))[1] == start]
        if not left or time.monotonic() > deadline:
            return len(left)
        time.sleep(0.1)


def checked(code: Path, out: Path, total: int, reference: dict) -> tuple[dict, bool]:
    """(what a finished dataset shows, whether it is all it must be)."""
    after = opened(code, out)
    verify = subprocess.run([*dotsim_command(code), "verify", str(out)], cwd=code,
                            env={**os.environ, "PYTHONPATH": str(code)}, capture_output=True, text=True)
    ok = (after["ok"] and after["scenes"] == list(range(total)) and frame_sums(out) == reference
          and not list(out.rglob(".tmp-*")) and verify.returncode == 0)
    return {"after": after if not after["ok"] else {"ok": True, "scenes": len(after["scenes"])},
            "verify_exit": verify.returncode}, ok


def opened(code: Path, out: Path) -> dict:
    done = subprocess.run([sys.executable, "-c", CHECK, str(out)], cwd=code, capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(code)})
    return json.loads(done.stdout)


def frame_sums(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.glob("shard_*/scene_*/frame_*.exr"))}


def complete(root: Path) -> int:
    return len(list(root.glob("shard_*/scene_*/scene.json")))


def index_scenes(root: Path) -> int | None:
    try:
        return json.loads((root / "index.json").read_text())["scene_count"]
    except (OSError, ValueError, KeyError):
        return None


def kill_trial(code: Path, base: Path, out: Path, total: int, delay: float | None, rng: random.Random,
               reference: dict, workers: int) -> dict:
    for attempt in range(KILL_ATTEMPTS):  # a run that ended before its kill is tried again, sooner
        shutil.rmtree(out, ignore_errors=True)
        shutil.copytree(base, out)
        proc = generate(code, out, total, "--workers", str(workers))
        start = time.perf_counter()
        if delay is None:  # wait for the last scene, then kill in or around the seal
            last = out / f"shard_{(total - 1) // 2:05d}" / f"scene_{total - 1:07d}"
            while not last.exists() and proc.poll() is None:
                time.sleep(0.002)
            time.sleep(rng.uniform(0.0, 0.3 / 2 ** attempt))
        else:
            time.sleep(delay / 2 ** attempt)
        killed_at = time.perf_counter() - start
        family = process_tree(proc.pid)
        finished = proc.poll() is not None
        if not finished:
            os.kill(proc.pid, signal.SIGKILL)  # the main process alone, as `kill -9 PID`
        proc.wait()
        if not finished:
            break
    left_running = orphans(family)
    left = {"complete": complete(out), "index": index_scenes(out), "opens": opened(code, out)["ok"],
            "leftovers": len(list(out.rglob(".tmp-*")))}
    code_rerun, last_line = run(code, out, total, "--workers", str(workers))
    after, ok = checked(code, out, total, reference)
    return {"killed_at": round(killed_at, 2), "finished_before_kill": finished, "attempts": attempt + 1,
            "processes": len(family),
            "orphans": left_running, "left": left, "rerun_exit": code_rerun, "rerun": last_line, **after,
            "ok": ok and code_rerun == 0 and left_running == 0}


def ray_worker_trial(code: Path, base: Path, out: Path, total: int, reference: dict, workers: int) -> dict:
    """`--ray local`: kill one Ray worker process mid-scene; the run must still end right, leaving nothing."""
    shutil.rmtree(out, ignore_errors=True)
    shutil.copytree(base, out)
    proc = generate(code, out, total, "--workers", str(workers), "--ray", "local")
    family: dict[int, int] = {}
    victim = None
    while proc.poll() is None:
        family.update(process_tree(proc.pid))
        if victim is None and list(out.glob("shard_*/.tmp-scene_*")):
            rendering = [pid for pid in family if "_render_task" in _cmdline(pid)]
            if rendering:
                victim = rendering[0]
                os.kill(victim, signal.SIGKILL)
        time.sleep(0.05)
    text, _ = proc.communicate()
    left_running = orphans(family)
    after, ok = checked(code, out, total, reference)
    last = text.strip().splitlines()[-1] if text.strip() else ""
    return {"killed_worker": victim is not None, "processes": len(family), "orphans": left_running,
            "exit": proc.returncode, "run": last, **after,
            "ok": ok and proc.returncode == 0 and victim is not None and left_running == 0}


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_text().replace("\0", " ")
    except OSError:
        return ""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("/tmp/dotsim_kill_trials"))
    parser.add_argument("--code", type=Path, default=REPO,
                        help="checkout whose dotsim runs (default: this one)")
    parser.add_argument("--base", type=int, default=12, help="scenes sealed before the extension")
    parser.add_argument("--extra", type=int, default=4, help="scenes the extension adds")
    parser.add_argument("--trials", type=int, default=10, help="kills at a random moment")
    parser.add_argument("--during-seal", type=int, default=5, help="kills just after the last scene")
    parser.add_argument("--ray-trials", type=int, default=1,
                        help="--ray local runs with one Ray worker killed mid-scene (needs ray)")
    parser.add_argument("--workers", type=int, default=2, help="render workers of each run (default 2)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.ray_trials and importlib.util.find_spec("ray") is None:
        print('no ray here (pip install "dotsim[ray]"): the --ray local trials are left out')
        args.ray_trials = 0
    code, total = args.code.resolve(), args.base + args.extra
    args.out.mkdir(parents=True, exist_ok=True)
    base, reference_dir, trial_dir = args.out / "base", args.out / "reference", args.out / "trial"
    # Made afresh each run: a base left by another run (other sizes, an older checkout's config)
    # would make every rerun refuse the folder as holding other settings.
    for folder, scenes in ((base, args.base), (reference_dir, total)):
        shutil.rmtree(folder, ignore_errors=True)
        status, line = run(code, folder, scenes)
        print(f"{folder.name}: exit {status}: {line}", flush=True)
    reference = frame_sums(reference_dir)
    # Time one extension, so random kills cover all of it (start-up, scenes, seal).
    shutil.rmtree(trial_dir, ignore_errors=True)
    shutil.copytree(base, trial_dir)
    start = time.perf_counter()
    run(code, trial_dir, total, "--workers", str(args.workers))
    span = time.perf_counter() - start
    print(f"one {args.base} -> {total} extension takes {span:.1f} s here", flush=True)
    rng = random.Random(args.seed)
    results = []
    for k in range(args.trials + args.during_seal):
        delay = rng.uniform(0.0, span) if k < args.trials else None
        result = kill_trial(code, base, trial_dir, total, delay, rng, reference, args.workers)
        results.append(result)
        print(f"trial {k + 1}: {json.dumps(result)}", flush=True)
    for k in range(args.ray_trials):
        result = ray_worker_trial(code, base, trial_dir, total, reference, args.workers)
        results.append(result)
        print(f"ray trial {k + 1}: {json.dumps(result)}", flush=True)
    # The damaged scene: a frame deleted from a complete scene, then the same command again.
    shutil.rmtree(trial_dir, ignore_errors=True)
    shutil.copytree(reference_dir, trial_dir)
    (trial_dir / "shard_00001" / "scene_0000003" / "frame_2.exr").unlink()
    status, line = run(code, trial_dir, total)
    damaged_ok = status == 0 and frame_sums(trial_dir) == reference and opened(code, trial_dir)["ok"]
    print(f"damaged scene rerun: exit {status}: {line}; byte-identical and opens: {damaged_ok}")
    good = sum(r["ok"] for r in results)
    kills = [r for r in results if "left" in r and not r["finished_before_kill"]]
    stale = sum(1 for r in kills if not r["left"]["opens"] or r["left"]["index"] != r["left"]["complete"])
    orphaned = sum(r["orphans"] for r in results)
    ray = [r for r in results if "left" not in r]
    print(f"summary: {good} of {len(results)} trials right ({len(kills)} kills -9 of a running main process, "
          f"{sum(r['killed_worker'] for r in ray)} --ray local runs with a worker killed mid-scene); "
          f"{orphaned} orphaned "
          f"process(es) {ORPHAN_WAIT_S:.0f} s after a kill or a run's end, over "
          f"{sum(r['processes'] for r in results)} processes the runs had; {stale} kill(s) left a stale or "
          f"broken seal before the rerun; damaged scene redone: {damaged_ok}")
    return 0 if good == len(results) and damaged_ok else 1


if __name__ == "__main__":
    sys.exit(main())
