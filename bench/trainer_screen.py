"""Step-matched screens of training changes: each variant of a config trains the same number of steps on
the same frames with one torch thread, and is scored on held-out validation frames (never the test
split); what a step of it costs is counted, not timed (timings on a shared machine mean nothing).

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
"""

from __future__ import annotations

import argparse
import json
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
from trainer.config import config_from_dict, load_config, output_rows
from trainer.metrics import THRESHOLDS
from trainer.model import build_model
from trainer.scoring import DEPTH_BINS, NetworkMethod, Scorer, depth_ranges
from trainer.train import train

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
    scorer = Scorer([NetworkMethod(model, rig, device)], rig, validation.pattern, bins, classes=classes,
                    thresholds=BY_CLASS_THRESHOLDS)
    for ref in validation.held_out(count, data, "training"):
        scorer.add(ref)
    return {r["range"]: {f"o({t:g})": r[f"o({t:g})"] for t in BY_CLASS_THRESHOLDS} | {"pixels": r["pixels"]}
            for r in scorer.rows()}


def read_results(folder: Path) -> list[dict]:
    """The lines of folder's results.jsonl, in the order they were written."""
    return [json.loads(line) for line in (folder / "results.jsonl").read_text().splitlines() if line]


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
    o(0.5) / o(5) by depth range and pixel class."""
    rows = read_results(folder)
    keys = [f"{c} o({t:g})" for c in ("all", "solvable") for t in (0.5, 5.0)]
    lines = ["| variant | settings | steps | GFLOP/step | parameters (M) | last loss | "
             + " | ".join(keys) + " |", "|" + "---|" * (6 + len(keys))]
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
    args = parser.parse_args(argv)
    if args.report:
        print(report(args.report))
        return 0
    if args.data is None or args.val_data is None:
        parser.error("--data and --val-data are needed (or --report DIR)")
    torch.set_num_threads(args.threads)
    source = open_source(args.data, args.split)
    frames, rig = source.frames, source.rig
    validation = open_source(args.val_data, args.val_split)
    base = with_settings(load_config(args.config).to_dict(), args.set)
    spe = max(len(frames) // base["train"]["batch_size"], 1)
    sized = sized_config(base, args.steps, max(1, round(args.steps / spe)), args.config).to_dict()
    sized["train"]["val_every"] = args.steps  # scored once, at the end
    cfg = config_from_dict(sized, f"{args.config} with {args.set}")
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
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "results.jsonl", "a") as f:
        f.write(json.dumps(line) + "\n")
    print(json.dumps(line))
    return 0


if __name__ == "__main__":
    sys.exit(main())
