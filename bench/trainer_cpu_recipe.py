"""What each CPU training-speed idea would buy, by counting, plus an optional short timing.

    python -m bench.trainer_cpu_recipe [--config train_cpu] [--time 20 [--rounds 3] [--compile]] [--threads 1]

Counts (exact, machine-independent): the FLOPs of one training step (forward and backward, batch
[train].batch_size) split into the backbone's convolutions and the tree's heads, for several crop
sizes, with torch's FlopCounterMode on a real network of the config at 608 x 448; and the parameters
Adam reads and writes every step (it updates every table entry, though a batch touches few). What the
counts say about each idea:

- crops / row bands: the backbone's FLOPs grow with the pixels of the crop, so samples/s in pixels
  is fixed by the backbone; a crop buys nothing per pixel, only more distinct images per step;
- sampling pixels for the branch heads: the heads run on the valid pixels only and are the small
  share printed below, so sampling them can save at most that share;
- channels_last and torch.compile change no count: only a timing can tell (--time N: rounds of N
  steps of each, taking turns after 3 warm-up steps, on synthetic batches; --compile adds
  torch.compile of the backbone; the load average is printed, since on a shared machine the figures
  are noise-prone).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import torch
from torch.utils.flop_counter import FlopCounterMode

from dotsim.rig.presets import get_preset
from trainer.config import load_config, output_rows
from trainer.model import GigaDepthNet, build_model

CROPS = ((96, 64), (192, 128), (304, 224), (608, 448))  # (width, height), full-resolution px
VALID_SHARE = 0.55  # share of visible pixels (dotsim stats on make dataset's data: about this)


def synthetic_batch(cfg, rows: int, width: int, height: int, seed: int = 0) -> dict:
    """A random batch of crops of width x height full-resolution px for a network with `rows` output
    rows (trainer.config.output_rows)."""
    g = torch.Generator().manual_seed(seed)
    b, stride = cfg.train.batch_size, cfg.model.stride
    h, w = -(-height // stride), -(-width // stride)
    return {"ir": torch.rand(b, 1, height, width, generator=g),
            "row0": torch.randint(0, max(rows - h, 0) + 1, (b,), generator=g),
            "x0": torch.zeros(b, dtype=torch.long),
            "column": torch.rand(b, h, w, generator=g),
            "valid": torch.rand(b, h, w, generator=g) < VALID_SHARE,
            "edge": torch.zeros(b, h, w)}


def step_loss(model: GigaDepthNet, batch: dict) -> torch.Tensor:
    terms = model.loss_terms(model.features(batch["ir"]), batch["row0"], batch["column"], batch["valid"],
                             batch["x0"])
    return sum(ce.sum() for ce in terms["ce"]) + terms["l1"].sum()


def count(model: GigaDepthNet, batch: dict) -> tuple[float, float]:
    """(backbone GFLOP, heads GFLOP) of one forward + backward."""
    with FlopCounterMode(display=False) as backbone_counter:
        feat = model.features(batch["ir"])
        feat.sum().backward()
    model.zero_grad(set_to_none=True)
    with FlopCounterMode(display=False) as total_counter:
        step_loss(model, batch).backward()
    model.zero_grad(set_to_none=True)
    backbone = backbone_counter.get_total_flops()
    return backbone / 1e9, (total_counter.get_total_flops() - backbone) / 1e9


def timed_variants(cfg, rig, batch: dict, steps: int, rounds: int, compile_backbone: bool) -> dict:
    """Median steps/s per variant of the same network: contiguous (as trained), channels_last, and
    with --compile the backbone through torch.compile. The variants take turns, `rounds` rounds of
    `steps` steps each after their warm-up, so a load that comes and goes falls on all of them; the
    compile's own time is reported apart."""
    variants = {"contiguous (as trained)": (build_model(cfg, rig), batch)}
    model = build_model(cfg, rig).to(memory_format=torch.channels_last)
    variants["channels_last"] = (model, {**batch, "ir": batch["ir"].contiguous(
        memory_format=torch.channels_last)})
    if compile_backbone:
        model = build_model(cfg, rig)
        model.backbone = torch.compile(model.backbone)
        variants["torch.compile (backbone)"] = (model, batch)
    opts = {name: torch.optim.Adam(model.parameters(), lr=1e-4, fused=True)
            for name, (model, _) in variants.items()}
    # warm-up: first-step allocations, and the compile itself
    warm_up = {name: run_steps(*variants[name], opts[name], 3) for name in variants}
    rates: dict[str, list[float]] = {name: [] for name in variants}
    for _ in range(rounds):
        for name in variants:
            rates[name].append(steps / run_steps(*variants[name], opts[name], steps))
    return {"rates": {name: statistics.median(r) for name, r in rates.items()},
            "compile_s": warm_up.get("torch.compile (backbone)")}


def run_steps(model: GigaDepthNet, batch: dict, opt, steps: int) -> float:
    """Seconds for `steps` optimiser steps on `batch`."""
    start = time.perf_counter()
    for _ in range(steps):
        opt.zero_grad(set_to_none=True)
        step_loss(model, batch).backward()
        opt.step()
    return time.perf_counter() - start


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default="train_cpu")
    parser.add_argument("--time", type=int, default=0, metavar="N", help="also time N steps of each idea")
    parser.add_argument("--rounds", type=int, default=3, help="--time: rounds, the variants taking turns")
    parser.add_argument("--compile", action="store_true", help="--time: also torch.compile the backbone "
                        "(inductor builds C++ first: minutes on 2 cores)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    cfg = load_config(args.config)
    rig = get_preset("structure_core").scaled(0.5)  # 608 x 448
    rows = output_rows(cfg.model, rig.camera.height)
    torch.manual_seed(0)
    model = build_model(cfg, rig)
    params = sum(p.numel() for p in model.parameters())
    backbone_params = sum(p.numel() for p in model.backbone.parameters())
    print(f"{args.config} at {rig.camera.width} x {rig.camera.height}: {params / 1e6:.1f} M parameters "
          f"({backbone_params / 1e3:.0f} k in the backbone); Adam reads and writes all of them every step "
          f"({4 * params * 4 / 1e6:.0f} MB of parameter, gradient and two moment tensors)\n")
    print("| crop (px) | batch | backbone GFLOP/step | heads GFLOP/step | heads share | "
          "MFLOP per full-res px |\n|---|---|---|---|---|---|")
    for width, height in CROPS:
        batch = synthetic_batch(cfg, rows, width, height)
        backbone, heads = count(model, batch)
        pixels = cfg.train.batch_size * width * height
        print(f"| {width} x {height} | {cfg.train.batch_size} | {backbone:.2f} | {heads:.3f} | "
              f"{heads / (backbone + heads):.1%} | {(backbone + heads) * 1e3 / pixels:.3f} |")
    if args.time:
        crop = (cfg.data.crop_width or rig.camera.width, cfg.data.crop_height or rig.camera.height)
        batch = synthetic_batch(cfg, rows, *crop)
        load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
        timed = timed_variants(cfg, rig, batch, args.time, args.rounds, args.compile)
        print(f"\nsteps/s, median of {args.rounds} rounds of {args.time} steps taking turns, {crop[0]} x "
              f"{crop[1]} crops, {args.threads} thread(s); load average before timing {load} (on a busy "
              "machine the ratios are noise-prone):")
        base = timed["rates"]["contiguous (as trained)"]
        for name, rate in timed["rates"].items():
            print(f"  {name}: {rate:.2f} ({rate / base:.2f}x)")
        if timed["compile_s"] is not None:
            print(f"  torch.compile's first steps (compiling): {timed['compile_s']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
