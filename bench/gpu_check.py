"""The prepared GPU check: the CUDA paths of train / eval / infer run, timed and trained, in one command.

A GPU machine is at hand only now and then, for minutes; this script is what such a session runs, in
one call of at most 9 minutes, writing its results as it goes so that a cut-off run still reports.
On the device machine (docs/TRAINER.md "The prepared check" has the exact command and what it carries):

    python3 -m bench.gpu_check --train 'gpu/train/shard-{000000..000006}.tar' --test gpu/test \
        --out $OUT --minutes 7

Sections, in this order, each within its share of --minutes:

1. environment: GPU, driver, CUDA, torch, numpy, Python;
2. inference of the published network (dotsim/configs/train_gigadepth.toml, random weights) on one
   1216 x 896 oracle frame: ms per frame (median, synchronised) in float32, bfloat16 and float16,
   eager, torch.compile of the backbone (its compile time too) and the backbone replayed from a CUDA
   graph (the tree's routing has data-dependent shapes, so only the backbone can be captured), peak
   memory of each; where the best eager time is slower than the published 60 ms, a torch.profiler
   table of its top ops (OUT/profile.txt);
3. training: ms per optimiser step, samples/s and peak memory of train_gigadepth (batch 4 of full
   1216 x 896 oracle frames) and train_cpu (batch 4 of its 96 x 64 crops of the carried frames);
4. accuracy: train_cpu on the carried training shards (`dotsim export --precision training`) for the
   steps the section's time allows at the rate section 3 measured, then `dotsim eval` on the carried
   test shards against StereoSGBM, its preprocessing chosen on training frames (OUT/eval.md);
5. tests: the CUDA tests and the precision tests (pytest in a subprocess, OUT/tests.log), in the time
   left.

Only when asked (`--sections table2`, alone, with its own carried shards), table2: GigaDepth's Table 2
   conditions on the GPU: --table2-config (train_table2) on full frames of the carried Table 2 training
   shards for the section's time, its learning-rate schedule sized to the steps that fit, then o(0.5)
   and o(5) of the network on frames spread over the carried like-for-like and disjoint test shards:
   one point of bench.trainer_scaling's curve, written as a line of its results.jsonl
   (OUT/table2_point.jsonl; docs/TRAINER.md "The scaling curve").

OUT/gpu_check.json is rewritten after every measurement; OUT/gpu_check.md summarises at the end.
`--device cpu --small` runs every section on CPU at 122 x 90 with dotsim/configs/train_tiny.toml (the
test suite's dry run: tests/bench/test_gpu_check.py), as a check that the script works, not figures.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from bench.trainer_accuracy import sized_config
from bench.trainer_gpu import (
    PUBLISHED_MS,
    median_seconds,
    profile_table,
    sync,
    training_row,
    variant_backbone,
)
from bench.trainer_scaling import curve_point, pixel_samples_per_step
from dotsim.file_io import atomic_write_bytes, atomic_write_json
from dotsim.frame_source import open_source
from dotsim.oracle_dataset import TINY_SCALE, make_dataset, random_depth, synthetic_frame
from dotsim.patterns import generate_dot_pattern
from dotsim.rig.presets import get_preset
from trainer.checkpoint import CHECKPOINT, PRECISIONS
from trainer.config import config_from_dict, load_config
from trainer.evaluate import evaluate, overall
from trainer.metrics import ratio
from trainer.model import autocast, build_model
from trainer.samples import FrameDataset
from trainer.train import train

CUDA_TESTS = ("tests/trainer/test_trainer_cuda.py", "tests/trainer/test_trainer_precision.py")
# Each section's share of --minutes (of the shares of the sections run); the tests take what is left.
SECTION_SHARES = {"inference": 0.22, "training": 0.10, "accuracy": 0.34, "table2": 1.0, "tests": 0.34}
DEFAULT_SECTIONS = ("inference", "training", "accuracy", "tests")  # table2 needs its own carried shards


class Report:
    """The results so far, rewritten to OUT/gpu_check.json after every item, and printed as lines."""

    def __init__(self, out: Path):
        self.out, self.results = out, {}
        out.mkdir(parents=True, exist_ok=True)

    def add(self, section: str, item, line: str | None = None) -> None:
        self.results.setdefault(section, []).append(_json_safe(item))
        atomic_write_json(self.out / "gpu_check.json", self.results)
        if line:
            print(line, flush=True)


def _json_safe(value):
    """`value` with non-finite floats as None (JSON has no NaN; a 'finite' flag says what happened)."""
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


class Clock:
    """Seconds since the start, and each section's deadline: the end of its share of the budget, the
    shares of the sections run (in SECTION_SHARES' order) laid end to end."""

    def __init__(self, minutes: float, sections: list[str]):
        self.start, self.total = time.monotonic(), minutes * 60
        run = [name for name in SECTION_SHARES if name in sections]
        whole = sum(SECTION_SHARES[name] for name in run)
        self.ends, end = {}, 0.0
        for name in run:
            end += SECTION_SHARES[name] / whole
            self.ends[name] = end

    def elapsed(self) -> float:
        return time.monotonic() - self.start

    def left(self, section: str | None = None) -> float:
        end = self.total * self.ends[section] if section else self.total
        return end - self.elapsed()


def environment(device: str) -> dict:
    info = {"python": platform.python_version(), "torch": torch.__version__, "numpy": np.__version__,
            "device": device}
    if device == "cuda":
        p = torch.cuda.get_device_properties(0)
        info |= {"gpu": p.name, "memory_gib": round(p.total_memory / 2**30, 1),
                 "multiprocessors": p.multi_processor_count, "cuda": torch.version.cuda,
                 "cudnn": torch.backends.cudnn.version()}
        try:
            info["driver"] = subprocess.run(
                ["nvidia-smi", "--query-gpu=driver_version", "--format=csv,noheader"], capture_output=True,
                text=True, timeout=20).stdout.strip()
        except (OSError, subprocess.TimeoutExpired):
            info["driver"] = "nvidia-smi not answering"
    return info


def peak_gib(device: str) -> float | None:
    return torch.cuda.max_memory_allocated() / 2**30 if device == "cuda" else None


def reset_peak(device: str) -> None:
    if device == "cuda":
        torch.cuda.reset_peak_memory_stats()


def inference_section(report: Report, clock: Clock, cfg, rig, device: str, repeats: int, variants: list[str],
                      out: Path) -> None:
    """ms per frame of the network in each precision and variant, peak memory; a profile if slow."""
    pattern = generate_dot_pattern(rig.projector.width, rig.projector.height, seed=0).image.astype(np.float64)
    rng = np.random.default_rng(0)
    ir = synthetic_frame(random_depth(rig, rng), rig, pattern, rng)["ir"].astype(np.float32)
    torch.manual_seed(0)
    model = build_model(cfg, rig).to(device).eval()
    x = torch.from_numpy(ir)[None, None].to(device)
    eager = model.backbone
    for variant in variants:
        for precision in PRECISIONS:
            if clock.left("inference") < 5:
                report.add("inference", {"skipped": f"{variant} {precision}: out of the section's time"},
                           f"  inference {variant} {precision}: skipped, out of the section's time")
                continue
            started = time.monotonic()
            try:
                model.backbone = variant_backbone(model, variant, x, precision)

                def forward(precision=precision):
                    with torch.no_grad(), autocast(device, precision):
                        return model(x)

                forward()  # compiles / warms up; timed as the variant's first call
                sync(device)
                first = time.monotonic() - started
                reset_peak(device)
                ms = median_seconds(forward, repeats, 2, device) * 1e3
                row = {"precision": precision, "variant": variant, "ms": ms, "first_call_s": first,
                       "peak_gib": peak_gib(device), "vs_published": ms / PUBLISHED_MS}
                line = (f"  inference {variant:<10} {precision:<9} {ms:8.2f} ms/frame "
                        f"({ms / PUBLISHED_MS:.2f} x the published 60 ms), first call {first:.1f} s")
                if row["peak_gib"] is not None:
                    line += f", peak {row['peak_gib']:.2f} GiB"
            except Exception as e:  # a variant that fails on this machine is a finding, not the end
                row = {"precision": precision, "variant": variant, "error": f"{type(e).__name__}: {e}"}
                line = f"  inference {variant} {precision}: FAILED {row['error'][:300]}"
            finally:
                model.backbone = eager
            report.add("inference", row, line)
    eager_ms = {r["precision"]: r["ms"] for r in report.results.get("inference", [])
                if r.get("variant") == "eager" and "ms" in r}
    if eager_ms and min(eager_ms.values()) > PUBLISHED_MS and clock.left("inference") > 0:
        precision = min(eager_ms, key=eager_ms.get)

        def forward():
            with torch.no_grad(), autocast(device, precision):
                model(x)

        table = profile_table(forward, device, 5)
        atomic_write_bytes(out / "profile.txt", f"inference, {precision}, eager, 5 runs\n{table}".encode())
        report.add("inference", {"profile": "profile.txt", "precision": precision},
                   f"  profile of eager {precision} inference (slower than {PUBLISHED_MS:g} ms): profile.txt")


def training_section(report: Report, clock: Clock, configs: dict, device: str, steps: int) -> dict:
    """ms per step and peak memory for each (config name -> (cfg, rig, batch)); returns the rows."""
    rows = {}
    for name, (cfg, rig, batch) in configs.items():
        for precision in ("float32", "bfloat16", "float16"):
            if clock.left("training") < 3:
                report.add("training", {"skipped": f"{name} {precision}"},
                           f"  training {name} {precision}: skipped, out of the section's time")
                continue
            reset_peak(device)
            row = training_row(cfg, batch, rig, device, precision, steps, 2)
            row |= {"config": name, "batch": list(batch["ir"].shape), "peak_gib": peak_gib(device)}
            rows[(name, precision)] = row
            peak = f", peak {row['peak_gib']:.2f} GiB" if device == "cuda" else ""
            report.add("training", row, f"  training {name:<25} {precision:<9} {row['ms_per_step']:8.1f} "
                       f"ms/step, {row['samples_per_s']:7.1f} samples/s{peak}, loss "
                       f"{row['first_loss']:.3f} -> {row['last_loss']:.3f}"
                       f"{'' if row['finite'] else ', NON-FINITE'}")
    return rows


def accuracy_section(report: Report, clock: Clock, cfg, train_data, test_data, device: str,
                     ms_per_step: float | None, max_steps: int, out: Path, work: Path) -> None:
    """Train `cfg` on the carried frames for the steps the section's time allows, then eval."""
    eval_seconds = 45 if device == "cuda" else 20  # SGBM on the CPU: ~0.2 s a frame and preprocessing
    seconds = clock.left("accuracy") - eval_seconds
    # the measured compute rate, with a quarter more for reading and cropping the frames
    per_step = 1.25 * (ms_per_step or 100.0) / 1e3
    planned = max(2, int(seconds / per_step)) if seconds > 0 else 2
    planned = min(planned, max_steps) if max_steps else planned
    d = cfg.to_dict()
    d["train"].update(max_steps=planned, checkpoint_every=10**9, image_every=10**9, epochs=10**6)
    d["data"]["workers"] = 0
    run = work / "accuracy_run"
    train_source = open_source(train_data, "train")
    started = time.monotonic()
    result = train(config_from_dict(d, "gpu_check accuracy run"), train_source, run, device=device,
                   progress=False, max_seconds=max(seconds, 1.0))
    took = time.monotonic() - started
    losses = np.asarray(result["losses"])
    k = max(1, min(50, len(losses) // 10))
    frames = len(train_source.frames)
    report.add("accuracy", {"planned_steps": planned, "steps": int(result["step"]), "seconds": took,
                            "steps_per_s": result["step"] / took, "train_frames": frames,
                            "loss_first": float(losses[:k].mean()), "loss_last": float(losses[-k:].mean())},
               f"  accuracy: {result['step']} steps (planned {planned}) in {took:.0f} s "
               f"({result['step'] / took:.1f} steps/s) on {frames} frames, loss {losses[:k].mean():.2f} -> "
               f"{losses[-k:].mean():.2f}")
    rows = evaluate(run / "checkpoint.pt", open_source(test_data, "test"), work / "eval", device=device,
                    images=2, progress=False, validation=train_source, val_frames=8)
    net = overall(rows, "network")
    sgbm = next(r for r in rows if r["chosen"] and r["range"] == "all")
    text = (work / "eval" / "eval.md").read_text()
    atomic_write_bytes(out / "eval.md", text.encode())
    report.add("accuracy", {"network": net, "sgbm": sgbm},
               f"  eval on {net['pixels']} valid test pixels: network o(0.5) {net['o(0.5)']:.4f} "
               f"o(5) {net['o(5)']:.4f}; {sgbm['method']} o(0.5) {sgbm['o(0.5)']:.4f} "
               f"o(5) {sgbm['o(5)']:.4f} "
               f"(ratio {ratio(net['o(0.5)'], sgbm['o(0.5)']):.2f}); OUT/eval.md")


def table2_section(report: Report, clock: Clock, cfg_name: str, data: dict[str, str], device: str,
                   max_steps: int, test_frames: int, out: Path, work: Path) -> None:
    """`cfg_name` on full frames of data["train"] for the section's time, then scored on `test_frames`
    frames spread over each test of `data`: a point of bench.trainer_scaling's curve."""
    base = load_config(cfg_name).to_dict()
    # GigaDepth's batches: whole frames (no crops, so no crops drawn around near pixels either)
    base["data"].update(crop_width=0, crop_height=0, near_share=0.0, workers=0)
    source = open_source(data["train"], "train")
    cfg = config_from_dict(base, f"{cfg_name} on full frames")
    rig, batch = first_batch(cfg, source)
    rate = training_row(cfg, batch, rig, device, cfg.train.amp, 5, 2)["ms_per_step"]
    tests = {name: open_source(data[key], "test") for key, name in
             (("seen", "seen meshes"), ("disjoint", "disjoint meshes")) if key in data}
    seconds = clock.left("table2") - 20 * (1 + len(tests))  # for scoring: the network, its frames read
    planned = max(2, int(seconds / (1.25 * rate / 1e3))) if seconds > 0 else 2
    planned = min(planned, max_steps) if max_steps else planned
    steps_per_epoch = max(len(source.frames) // cfg.train.batch_size, 1)
    cfg = sized_config(base, planned, math.ceil(planned / steps_per_epoch), f"{cfg_name} on full frames")
    run = work / "table2_run"
    started = time.monotonic()
    result = train(cfg, source, run, device=device, progress=False, max_seconds=max(seconds, 1.0))
    took = time.monotonic() - started
    report.add("table2", {"config": cfg_name, "ms_per_step": rate, "planned_steps": planned,
                          "steps": result["step"], "seconds": took, "train_frames": len(source.frames)},
               f"  table2: {cfg_name} on full frames, {result['step']} steps (planned {planned} at "
               f"{rate:.1f} ms/step) in {took:.0f} s on {len(source.frames)} frames")
    per_step = pixel_samples_per_step(cfg.train.batch_size, 0, 0, rig.camera.width, rig.camera.height)
    point = curve_point(run / CHECKPOINT, result["step"], per_step, cfg_name, source, tests, test_frames,
                        device)
    where = torch.cuda.get_device_name(0) if device == "cuda" else device
    point |= {"device": where, "full_frames": True, "seconds": took}
    atomic_write_bytes(out / "table2_point.jsonl", (json.dumps(point) + "\n").encode())
    rates = "; ".join(f"{name} o(0.5) {r['o(0.5)']:.4f} o(5) {r['o(5)']:.4f}"
                      for name, r in point["tests"].items())
    report.add("table2", point, f"  table2: {point['pixel_samples']:.3g} pixel-samples: {rates}; "
               "OUT/table2_point.jsonl")


def tests_section(report: Report, clock: Clock, tests: list[str], out: Path) -> None:
    timeout = clock.left() - 5
    if timeout < 20:
        report.add("tests", {"skipped": "out of time"}, "  tests: skipped, out of time")
        return
    log = out / "tests.log"
    with open(log, "wb") as stream:
        try:
            command = [sys.executable, "-m", "pytest", "-q", "-rs", "-p", "no:cacheprovider", *tests]
            code = subprocess.run(command, stdout=stream, stderr=subprocess.STDOUT,
                                  timeout=timeout).returncode
        except subprocess.TimeoutExpired:
            code = None
    lines = log.read_text(errors="replace").strip().splitlines()
    summary = lines[-1] if lines else ""
    report.add("tests", {"tests": tests, "returncode": code, "summary": summary},
               f"  tests: {'TIMED OUT after ' + format(timeout, '.0f') + ' s' if code is None else summary}")


def first_batch(cfg, source) -> tuple:
    """(rig, one training batch) of a FrameSource: the config's batch size of augmented crops, frames
    repeated when there are fewer (the dry run has 2)."""
    rig = source.rig
    ds = FrameDataset(source.frames, rig, cfg.data, cfg.seed, augment=True)
    samples = [ds[i % len(ds)] for i in range(cfg.train.batch_size)]
    return rig, {k: torch.stack([s[k] for s in samples]) for k in samples[0]}


def oracle_batch(cfg, scale: float, work: Path) -> tuple:
    """first_batch of 4 oracle frames at `scale` (written once under `work`)."""
    data = work / f"oracle_{scale:g}"
    if not (data / "index.json").exists():
        make_dataset(data, scenes=2, frames_per_scene=2, scale=scale)
    return first_batch(cfg, open_source(data, "train"))


def summary(results: dict) -> str:
    env = results.get("environment", [{}])[0]
    lines = [f"# GPU check on {env.get('gpu', env.get('device'))} (driver {env.get('driver', '-')}, "
             f"CUDA {env.get('cuda', '-')}, torch {env.get('torch')}, numpy {env.get('numpy')}, "
             f"Python {env.get('python')})", "", "| inference | precision | ms/frame | x published 60 ms | "
             "first call s | peak GiB |", "|---|---|---|---|---|---|"]
    for r in results.get("inference", []):
        if "ms" in r:
            peak = "-" if r["peak_gib"] is None else f"{r['peak_gib']:.2f}"
            lines.append(f"| {r['variant']} | {r['precision']} | {r['ms']:.2f} | {r['vs_published']:.2f} | "
                         f"{r['first_call_s']:.1f} | {peak} |")
    lines += ["", "| training | precision | ms/step | samples/s | peak GiB | loss first -> last |",
              "|---|---|---|---|---|---|"]
    for r in results.get("training", []):
        if "ms_per_step" in r:
            peak = "-" if r["peak_gib"] is None else f"{r['peak_gib']:.2f}"
            lines.append(f"| {r['config']} | {r['precision']} | {r['ms_per_step']:.1f} | "
                         f"{r['samples_per_s']:.1f} | {peak} | {r['first_loss']} -> {r['last_loss']} |")
    for r in results.get("accuracy", []) + results.get("table2", []) + results.get("tests", []):
        lines.append("")
        lines.append("- " + json.dumps(r))
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--train", help="training frames: an export folder, shards or a brace pattern "
                        "(`dotsim export --precision training`); the training and accuracy sections need it")
    parser.add_argument("--test", help="held-out test frames (split test), as --train; needed by accuracy")
    parser.add_argument("--out", required=True, type=Path, help="results folder ($OUT on the device)")
    parser.add_argument("--minutes", type=float, default=7.0, help="the whole check's budget (default 7; at "
                        "most 9 so one device call of 10 minutes holds it)")
    parser.add_argument("--device", choices=("cuda", "cpu"), default="cuda")
    parser.add_argument("--small", action="store_true", help="train_tiny at 122 x 90 for every section "
                        "(the CPU dry run)")
    parser.add_argument("--repeats", type=int, default=30, help="timed inference runs (median)")
    parser.add_argument("--train-steps", type=int, default=15, help="timed training steps (median)")
    parser.add_argument("--variants", default="eager,compile,cuda-graph",
                        help="inference variants, comma-separated (cuda-graph: CUDA only)")
    parser.add_argument("--max-steps", type=int, default=0, help="cap the accuracy run's steps (0: the time)")
    parser.add_argument("--tests", nargs="*", default=list(CUDA_TESTS), help="pytest paths for section 5")
    parser.add_argument("--sections", default=",".join(DEFAULT_SECTIONS),
                        help="which sections to run, comma-separated (a rerun of some: the others' shares of "
                        f"--minutes go to these; default {','.join(DEFAULT_SECTIONS)}; table2 only when "
                        "asked, with its own carried shards)")
    parser.add_argument("--table2-train", help="table2: Table 2 training frames, as --train")
    parser.add_argument("--table2-seen-test", help="table2: test frames of new scenes of the training meshes")
    parser.add_argument("--table2-test", help="table2: test frames of meshes never seen")
    parser.add_argument("--table2-config", help="table2: the training config (default train_table2; "
                        "train_tiny with --small)")
    parser.add_argument("--test-frames", type=int, default=16, help="table2: frames spread over each test")
    args = parser.parse_args(argv)
    sections = [name for name in args.sections.split(",") if name]
    if not 0 < args.minutes <= 9:
        parser.error(f"--minutes {args.minutes}: between 0 and 9")
    if unknown := set(sections) - set(SECTION_SHARES):
        parser.error(f"--sections: unknown {sorted(unknown)}; choose from {', '.join(SECTION_SHARES)}")
    for name, needs in (("training", ("train",)), ("accuracy", ("train", "test"))):
        if name in sections and (missing := [f"--{k}" for k in needs if not getattr(args, k)]):
            parser.error(f"the {name} section needs {' and '.join(missing)}")
    if "table2" in sections and not (args.table2_train and (args.table2_seen_test or args.table2_test)):
        parser.error("--sections table2 needs --table2-train and --table2-seen-test and/or --table2-test")
    if args.device == "cuda" and not torch.cuda.is_available():
        print("bench.gpu_check: no CUDA device (torch.cuda.is_available() is False); `--device cpu --small` "
              "dry-runs it on CPU", file=sys.stderr)
        return 1
    device, clock, report = args.device, Clock(args.minutes, sections), Report(args.out)
    if device == "cuda":
        torch.backends.cudnn.benchmark = True  # fixed input shapes: let cuDNN pick its fastest convolutions
    info = environment(device)
    report.add("environment", info, f"1. environment: {json.dumps(info)}")
    variants = [v for v in args.variants.split(",") if v and (v != "cuda-graph" or device == "cuda")]
    published_name, cpu_name = ("train_tiny",) * 2 if args.small else ("train_gigadepth", "train_cpu")
    published = load_config(f"dotsim/configs/{published_name}.toml")
    cpu_cfg = load_config(f"dotsim/configs/{cpu_name}.toml")
    scale = TINY_SCALE if args.small else 1.0
    rate = None
    with tempfile.TemporaryDirectory(prefix="gpu_check_") as tmp:
        work = Path(tmp)
        if "inference" in sections:
            size = "122 x 90" if args.small else "1216 x 896"
            print(f"2. inference ({published_name}, {size}):", flush=True)
            inference_section(report, clock, published, get_preset("structure_core").scaled(scale), device,
                              args.repeats, variants, args.out)
        if "training" in sections:
            print("3. training:", flush=True)
            cpu_batch = first_batch(cpu_cfg, open_source(args.train, "train"))
            configs = {f"{published_name} (oracle)": (published, *oracle_batch(published, scale, work)),
                       f"{cpu_name} (carried)": (cpu_cfg, *cpu_batch)}
            rows = training_section(report, clock, configs, device, args.train_steps)
            rate = rows.get((f"{cpu_name} (carried)", "float32"), {}).get("ms_per_step")
        if "accuracy" in sections:
            print("4. accuracy:", flush=True)
            accuracy_section(report, clock, cpu_cfg, args.train, args.test, device, rate, args.max_steps,
                             args.out, work)
        if "table2" in sections:
            name = args.table2_config or ("train_tiny" if args.small else "train_table2")
            print(f"table2 ({name} on full frames):", flush=True)
            carried = {"train": args.table2_train, "seen": args.table2_seen_test,
                       "disjoint": args.table2_test}
            table2_section(report, clock, name, {k: v for k, v in carried.items() if v}, device,
                           args.max_steps, args.test_frames, args.out, work)
        if "tests" in sections:
            print("5. tests:", flush=True)
            tests_section(report, clock, args.tests, args.out)
    atomic_write_bytes(args.out / "gpu_check.md", summary(report.results).encode())
    print(f"gpu check done in {clock.elapsed():.0f} s: {args.out / 'gpu_check.md'}, gpu_check.json",
          flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
