"""Reliability trials: kill -9 while extending a sealed dataset, then rerun; and a damaged scene.

    python -m bench.kill_trials --trials 10 --during-seal 5 --out /tmp/kill_trials

1. Renders N scenes (--base, dotsim/configs/tiny.toml, sealed) and, once, N + M scenes (--extra) as the
   reference. Each trial copies the sealed N-scene dataset, starts `dotsim generate --scenes N+M`
   in its own process group and kills the group with SIGKILL at a random moment (uniform over the
   time a whole extension takes; --during-seal trials wait for the last scene folder and kill
   0-300 ms later, inside or around the seal). It records what the kill left (complete scenes,
   scenes index.json lists, whether open_dataset(verify=True) passes), reruns the same command to
   completion, and checks: exit status 0, open_dataset(verify=True) lists all N + M scenes, every
   frame byte-identical to the reference, no `.tmp-` leftovers, `dotsim verify` clean.
2. Damaged scene: a frame deleted from a complete scene; the rerun must redo it byte-identically.

Prints one line per trial and a summary. The commands run with the Python that runs this module,
from --code (default: this repository), so an older checkout can be tried the same way.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

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


def generate(code: Path, out: Path, scenes: int, **popen) -> subprocess.Popen:
    command = [sys.executable, "-m", "dotsim.cli", "generate", "--config", "tiny",
               "--out", str(out), "--split", "train", "--scenes", str(scenes), "--seed", "3", "--no-progress"]
    return subprocess.Popen(command, cwd=code, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            **popen)


def run(code: Path, out: Path, scenes: int) -> tuple[int, str]:
    proc = generate(code, out, scenes)
    text, _ = proc.communicate()
    return proc.returncode, text.strip().splitlines()[-1] if text.strip() else ""


def opened(code: Path, out: Path) -> dict:
    done = subprocess.run([sys.executable, "-c", CHECK, str(out)], cwd=code, capture_output=True, text=True)
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
               reference: dict) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    shutil.copytree(base, out)
    proc = generate(code, out, total, start_new_session=True)
    start = time.perf_counter()
    if delay is None:  # wait for the last scene, then kill in or around the seal
        last = out / f"shard_{(total - 1) // 2:05d}" / f"scene_{total - 1:07d}"
        while not last.exists() and proc.poll() is None:
            time.sleep(0.002)
        time.sleep(rng.uniform(0.0, 0.3))
    else:
        time.sleep(delay)
    killed_at = time.perf_counter() - start
    finished = proc.poll() is not None
    if not finished:
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    left = {"complete": complete(out), "index": index_scenes(out), "opens": opened(code, out)["ok"],
            "leftovers": len(list(out.rglob(".tmp-*")))}
    code_rerun, last_line = run(code, out, total)
    after = opened(code, out)
    verify = subprocess.run([sys.executable, "-m", "dotsim.cli", "verify", str(out)], cwd=code,
                            capture_output=True, text=True)
    ok = (code_rerun == 0 and after["ok"] and after["scenes"] == list(range(total))
          and frame_sums(out) == reference and not list(out.rglob(".tmp-*")) and verify.returncode == 0)
    return {"killed_at": round(killed_at, 2), "finished_before_kill": finished, "left": left,
            "rerun_exit": code_rerun, "rerun": last_line, "after": after if not after["ok"] else
            {"ok": True, "scenes": len(after["scenes"])}, "verify_exit": verify.returncode, "ok": ok}


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
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
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
    run(code, trial_dir, total)
    span = time.perf_counter() - start
    print(f"one {args.base} -> {total} extension takes {span:.1f} s here", flush=True)
    rng = random.Random(args.seed)
    results = []
    for k in range(args.trials + args.during_seal):
        delay = rng.uniform(0.0, span) if k < args.trials else None
        result = kill_trial(code, base, trial_dir, total, delay, rng, reference)
        results.append(result)
        print(f"trial {k + 1}: {json.dumps(result)}", flush=True)
    # The damaged scene: a frame deleted from a complete scene, then the same command again.
    shutil.rmtree(trial_dir, ignore_errors=True)
    shutil.copytree(reference_dir, trial_dir)
    (trial_dir / "shard_00001" / "scene_0000003" / "frame_2.exr").unlink()
    status, line = run(code, trial_dir, total)
    damaged_ok = status == 0 and frame_sums(trial_dir) == reference and opened(code, trial_dir)["ok"]
    print(f"damaged scene rerun: exit {status}: {line}; byte-identical and opens: {damaged_ok}")
    good = sum(r["ok"] for r in results)
    stale = sum(1 for r in results if not r["left"]["opens"] or r["left"]["index"] != r["left"]["complete"])
    print(f"summary: {good} of {len(results)} kill trials mended by one rerun ({stale} left a stale or "
          f"broken seal before the rerun); damaged scene redone: {damaged_ok}")
    return 0 if good == len(results) and damaged_ok else 1


if __name__ == "__main__":
    sys.exit(main())
