"""Step-matched screens of training changes: each variant of a config trains the same number of steps on
the same frames with one torch thread, and is scored on held-out validation frames (never the test
split); what a step of it costs is counted here (timings of runs that share a machine mean nothing)
and timed apart with --time (below).

    python -m bench.trainer_screen --config train_cpu --data out/gpu/train --val-data out/gpu_val \
        --steps 3000 --name min_depth --set model.min_depth=0.2 --out out/screens/cpu
    python -m bench.trainer_screen --report out/screens/cpu

Each run appends one line to OUT/results.jsonl: the variant's name and settings (`--set SECTION.KEY=VALUE`,
VALUE in TOML, any number of them), the steps, the mean loss of its last tenth, the validation o(t) of
the network over the valid and the solvable pixels (trainer.scoring.Validation, `--val-frames` frames spread
over --val-data), GFLOP per training step (forward and backward at the config's crop and batch, torch's
FlopCounterMode, bench.trainer_cpu_recipe.count) and the parameters, and the trained network's o(t) on
the same frames by GT depth range and on / off the edge mask (`by_class`: the rows eval.md has; a
change aimed at near surfaces or edges shows there first). The run's length is sized as
bench.trainer_accuracy sizes it (step decay at 25, 50 and 75 % of the steps). `--report` prints the
tables of a folder's lines; `--rescore --name N` scores N's checkpoint by class again (for classes added
since it ran, as "slanted") and rewrites its line. Variants that ran at the same time on a shared
machine still compare: the steps, not the minutes, are equal.

What a step costs in time is the other half of a variant's price, since a fixed hour decides:

    python -m bench.trainer_screen --config train_table2 --data data/table2c/train --time 24 \
        --name lines_256 --set model.lines=256 --out out/screens/t2c_2400

times the variant's training step against the config's own on a quiet machine, in one process: each
trains --time real batches of --data per round (the same frames and crops for both, trainer.train's
step: loss, backward, optimiser, schedule), --rounds rounds after a warm-up, taking turns, so a load
that comes and goes falls on both. It appends to OUT/timings.jsonl the seconds per step of every round,
their medians and the variant / config ratio round by round (median, min, max); `--report` prints them.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
import tomllib
from pathlib import Path

import torch

from bench.trainer_accuracy import sized_config
from bench.trainer_cpu_recipe import count, synthetic_batch
from dotsim.file_io import atomic_write_bytes
from dotsim.frame_source import FrameSource, open_source
from trainer.checkpoint import CHECKPOINT, load_model
from trainer.config import Config, config_from_dict, load_config, output_rows
from trainer.distributed import ONE_PROCESS
from trainer.metrics import THRESHOLDS
from trainer.model import build_model
from trainer.samples import FrameDataset, make_loader
from trainer.scoring import DEPTH_BINS, NetworkMethod, Scorer, depth_ranges
from trainer.train import (
    TrainingLoss,
    keep_freed_memory,
    new_state,
    optimiser_step,
    plan_steps,
    seed_everything,
    train,
)
from trainer.upsampling import pattern_reference

BY_CLASS_THRESHOLDS = (0.5, 5.0)


def with_settings(base: dict, settings: list[str]) -> dict:
    """A copy of base (a config's dict) with SECTION.KEY=VALUE settings (VALUE in TOML) applied.

    >>> base = {"seed": 0, "model": {"lines": 45, "min_depth": 0.0}, "train": {"lr_schedule": "step"}}
    >>> with_settings(base, ["model.min_depth=0.2", 'train.lr_schedule = "cosine"', "seed=3"])
    {'seed': 3, 'model': {'lines': 45, 'min_depth': 0.2}, 'train': {'lr_schedule': 'cosine'}}
    >>> base["model"]["min_depth"]  # a copy
    0.0
    """
    d = json.loads(json.dumps(base))
    for setting in settings:
        key, _, text = setting.partition("=")
        section, _, name = key.strip().rpartition(".")
        value = tomllib.loads(f"v = {text.strip()}")["v"]
        (d[section] if section else d)[name] = value
    return d


def screened_config(config: str, settings: list[str], steps: int, frames: int) -> Config:
    """The config named `config` with `settings` (with_settings), sized as bench.trainer_accuracy sizes a
    run of `steps` steps over `frames` training frames, scored once, at the end."""
    base = with_settings(load_config(config).to_dict(), settings)
    steps_per_epoch = max(frames // base["train"]["batch_size"], 1)
    sized = sized_config(base, steps, max(1, round(steps / steps_per_epoch)), config).to_dict()
    sized["train"]["val_every"] = steps
    return config_from_dict(sized, f"{config} with {settings}")


def step_gflop(cfg, rig) -> float:
    """GFLOP of one training step (forward and backward) of cfg's network at its crop and batch."""
    model = build_model(cfg, rig)
    width = cfg.data.crop_width or rig.camera.width
    height = cfg.data.crop_height or rig.camera.height
    return sum(count(model, synthetic_batch(cfg, output_rows(cfg.model, rig.camera.height), width, height)))


def rates_by_class(checkpoint: Path, validation: FrameSource, data: FrameSource, count: int,
                   device: str = "cpu") -> dict[str, dict[str, float]]:
    """{class: {"o(t)": rate}} of a checkpoint's network (run on `device`) on `count` held-out frames of
    `validation`, per GT depth range (cut at the rig's max_depth), on / off the edge mask and slanted
    (trainer.scoring's Scorer)."""
    model, _, rig = load_model(checkpoint, device)
    bins = depth_ranges(DEPTH_BINS, rig.max_depth)
    ranges = (f"{a:g}-{b:g}" for a, b in zip(bins[:-1], bins[1:], strict=True))
    classes = ("all", *ranges, "edge", "off edge", "slanted")
    network = NetworkMethod(model, rig, device, reference=pattern_reference(validation.pattern, rig))
    scorer = Scorer([network], rig, validation.pattern, bins, classes=classes,
                    thresholds=BY_CLASS_THRESHOLDS)
    for ref in validation.held_out(count, data, "training"):
        scorer.add(ref)
    return {r["range"]: {f"o({t:g})": r[f"o({t:g})"] for t in BY_CLASS_THRESHOLDS} | {"pixels": r["pixels"]}
            for r in scorer.rows()}


def step_seconds(cfgs: dict[str, Config], source: FrameSource, batches: int, rounds: int
                 ) -> dict[str, list[float]]:
    """{name: seconds per training step in each round} of each config in cfgs, stepped as trainer.train
    steps (optimiser_step) through the first `batches` augmented batches of source's frames, the same
    for each config (its own crop and stride). After a warm-up of 2 steps each, `rounds` rounds; the
    configs take turns, in reversed order every other round. The process keeps freed memory as
    trainer.train's does (keep_freed_memory): without it each step's fresh gradient tables are paged
    in again, a cost that grows with the tables and that training does not pay."""
    keep_freed_memory()
    runs = {}
    for name, cfg in cfgs.items():
        seed_everything(cfg.seed)
        ds = FrameDataset(source.frames, source.rig, cfg.data, cfg.seed, augment=True,
                          stride=cfg.model.stride)
        loader = make_loader(ds, cfg.train.batch_size, 0, 0, cfg.data.workers)
        taken = [batch for batch, _ in zip(loader, range(batches), strict=False)]
        state = new_state(cfg, source.rig, "cpu", *plan_steps(cfg, source))
        state.model.train()
        runs[name] = (TrainingLoss(state.model, cfg, ONE_PROCESS), state, cfg, taken)

    def seconds_per_step(name: str, count: int) -> float:
        loss_of, state, cfg, taken = runs[name]
        start = time.perf_counter()
        for step, batch in enumerate(taken[:count]):
            optimiser_step(loss_of, state, batch, cfg, ONE_PROCESS, step, start)
        return (time.perf_counter() - start) / min(count, len(taken))

    for name in runs:
        seconds_per_step(name, 2)
    seconds: dict[str, list[float]] = {name: [] for name in runs}
    for r in range(rounds):
        for name in list(runs)[:: 1 if r % 2 == 0 else -1]:
            seconds[name].append(seconds_per_step(name, batches))
    return seconds


def timing_line(name: str, settings: list[str], seconds: dict[str, list[float]]) -> dict:
    """The timings.jsonl line of a variant's rounds against the config's (step_seconds' "config")."""
    ratios = [v / c for v, c in zip(seconds[name], seconds["config"], strict=True)]
    return {"name": name, "settings": settings, "seconds_per_step": seconds,
            "median_seconds": {k: statistics.median(v) for k, v in seconds.items()},
            "ratio": {"median": statistics.median(ratios), "min": min(ratios), "max": max(ratios)},
            "load_average": os.getloadavg()}


def read_results(folder: Path, file: str = "results.jsonl") -> list[dict]:
    """The lines of folder's results.jsonl (or `file`), in the order they were written."""
    return [json.loads(line) for line in (folder / file).read_text().splitlines() if line]


def append_line(results: Path, line: dict) -> None:
    """Append `line` to the JSON-lines file `results` (its folder made if need be) and print it."""
    results.parent.mkdir(parents=True, exist_ok=True)
    with open(results, "a") as f:
        f.write(json.dumps(line) + "\n")
    print(json.dumps(line), flush=True)


def rescore(folder: Path, name: str, by_class: dict) -> int:
    """Replace the by_class rates of the runs named `name` in folder's results.jsonl."""
    lines = read_results(folder)
    for line in lines:
        if line["name"] == name:
            line["by_class"] = by_class
    atomic_write_bytes(folder / "results.jsonl", "".join(json.dumps(line) + "\n" for line in lines).encode())
    print(json.dumps(by_class))
    return 0


def report(folder: Path) -> str:
    """The markdown tables of a folder's results, in the order they ran: the validation rates, then
    o(0.5) / o(5) by depth range and pixel class, then the step timings (timings.jsonl) where any ran."""
    rows = read_results(folder) if (folder / "results.jsonl").exists() else []
    keys = [f"{c} o({t:g})" for c in ("all", "solvable") for t in (0.5, 5.0)]
    lines = [] if not rows else [
        "| variant | settings | steps | GFLOP/step | parameters (M) | last loss | " + " | ".join(keys) + " |",
        "|" + "---|" * (6 + len(keys))]
    for r in rows:
        rates = " | ".join(f"{r['validation'][k]:.4f}" if k in r["validation"] else "-" for k in keys)
        lines.append(f"| {r['name']} | {', '.join(r['settings']) or 'as the config'} | {r['steps']} | "
                     f"{r['gflop_per_step']:.2f} | {r['parameters'] / 1e6:.1f} | {r['last_loss']:.3f} | "
                     f"{rates} |")
    classes = list(dict.fromkeys(c for r in rows for c in r.get("by_class", {})))
    if classes:
        lines += ["", "o(0.5) / o(5) by GT depth range (m) and pixel class:", "",
                  "| variant | " + " | ".join(classes) + " |", "|" + "---|" * (1 + len(classes))]
        for r in rows:
            cells = [f"{c['o(0.5)']:.3f} / {c['o(5)']:.3f}" if (c := r.get("by_class", {}).get(k))
                     and c["pixels"] else "-" for k in classes]
            lines.append(f"| {r['name']} | " + " | ".join(cells) + " |")
    if (folder / "timings.jsonl").exists():
        lines += ["", "Seconds per training step, the variant and the config taking turns in one process:",
                  "",
                  "| variant | settings | rounds x steps | config s/step | variant s/step | "
                  "ratio median (min-max) |", "|---|---|---|---|---|---|"]
        for t in read_results(folder, "timings.jsonl"):
            m, ratio = t["median_seconds"], t["ratio"]
            lines.append(f"| {t['name']} | {', '.join(t['settings']) or 'as the config'} | "
                         f"{len(t['seconds_per_step']['config'])} x {t['steps_per_round']} | "
                         f"{m['config']:.3f} | {m[t['name']]:.3f} | "
                         f"{ratio['median']:.2f} ({ratio['min']:.2f}-{ratio['max']:.2f}) |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default="train_cpu", help="training config: a built-in name or a file")
    parser.add_argument("--data", type=Path, help="dataset whose --split frames are trained on")
    parser.add_argument("--split", default="train")
    parser.add_argument("--val-data", type=Path, help="held-out dataset the variants are scored on")
    parser.add_argument("--val-split", default="all")
    parser.add_argument("--val-frames", type=int, default=8)
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--name", default="baseline")
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="a setting of the variant (TOML value), e.g. model.min_depth=0.2")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", type=Path, default=Path("out/screens"))
    parser.add_argument("--report", type=Path, metavar="DIR", help="print DIR's results table and exit")
    parser.add_argument("--rescore", action="store_true",
                        help="score --name's trained checkpoint in --out by class again (classes added since "
                             "it ran) and rewrite its line")
    parser.add_argument("--time", type=int, default=0, metavar="N",
                        help="instead of training: time the variant's step against the config's on N real "
                             "batches of --data per round, taking turns, into OUT/timings.jsonl")
    parser.add_argument("--rounds", type=int, default=6, help="--time: rounds")
    args = parser.parse_args(argv)
    if args.report:
        print(report(args.report))
        return 0
    if args.data is None or (args.val_data is None and not args.time):
        parser.error("--data and --val-data are needed (--time: --data; or --report DIR)")
    if args.time and args.name == "config":
        parser.error("--time: name the variant something other than 'config' (the config's own step)")
    torch.set_num_threads(args.threads)
    source = open_source(args.data, args.split)
    frames, rig = source.frames, source.rig
    cfg = screened_config(args.config, args.set, args.steps, len(frames))
    if args.time:
        seconds = step_seconds({"config": screened_config(args.config, [], args.steps, len(frames)),
                                args.name: cfg}, source, args.time, args.rounds)
        line = timing_line(args.name, args.set, seconds) | {
            "config": args.config, "data": str(args.data), "steps_per_round": args.time,
            "threads": args.threads}
        append_line(args.out / "timings.jsonl", line)
        return 0
    validation = open_source(args.val_data, args.val_split)
    run = args.out / args.name
    if args.rescore:
        by_class = rates_by_class(run / CHECKPOINT, validation, source, args.val_frames)
        return rescore(args.out, args.name, by_class)
    start = time.perf_counter()
    result = train(cfg, source, run, progress=False, validation=validation, val_frames=args.val_frames)
    last = result["losses"][-max(len(result["losses"]) // 10, 1):]
    line = {"name": args.name, "config": args.config, "settings": args.set, "steps": result["step"],
            "data": str(args.data), "val_data": str(args.val_data), "frames": len(frames),
            "last_loss": sum(last) / max(len(last), 1),
            "validation": result["validation"],
            "by_class": rates_by_class(run / CHECKPOINT, validation, source, args.val_frames),
            "gflop_per_step": step_gflop(cfg, rig),
            "parameters": sum(p.numel() for p in build_model(cfg, rig).parameters()),
            "seconds_on_a_shared_machine": time.perf_counter() - start, "thresholds": list(THRESHOLDS)}
    append_line(args.out / "results.jsonl", line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
