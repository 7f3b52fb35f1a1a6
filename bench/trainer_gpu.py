"""The trainer on a GPU: training samples/s and peak memory, inference time per frame in float32, float16
and bfloat16 for the conv and UNet backbones, optional torch.compile / CUDA-graph variants side by side,
and a torch.profiler table of the top ops.

    python -m bench.trainer_gpu [--device cuda] [--small] [--repeats 50] [--train-run 300]
                                [--compile] [--cuda-graph] [--profile] [--out DIR]

Published config (dotsim/configs/train_gigadepth.toml), batch 4 of its crop (full 1216 x 896 frames), on
oracle-rendered frames (dotsim/oracle_dataset.py: tilted walls and boxes, made once under --out).
Inference: the network's forward on one frame already on the device, median of --repeats after
warm-up, each timed with torch.cuda.synchronize; networks have random weights unless --train-run
trained one (then the conv rows use it). --compile compiles the backbone with torch.compile; --cuda-graph
replays the backbone from a captured CUDA graph (the tree's per-pixel routing has data-dependent
shapes, so only the backbone can be captured). --train-run N trains N steps with train() in each low
precision and reports whether the loss fell, NaNs, and end-to-end samples/s (data loading included).
Without CUDA the bench says so and exits 0; `--device cpu --small` runs every part on CPU at 122 x 90
with dotsim/configs/train_tiny.toml, as a check that it works (not figures to report).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

from dotsim.frame_source import open_source
from dotsim.oracle_dataset import TINY_SCALE, make_dataset, random_depth, synthetic_frame
from dotsim.patterns import generate_dot_pattern
from trainer.checkpoint import PRECISIONS, load_model, predict_disparity
from trainer.config import config_from_dict, load_config
from trainer.model import LOW_PRECISION, autocast, build_model
from trainer.samples import FrameDataset, make_loader
from trainer.train import batch_loss, make_optimizer, train

PUBLISHED_MS = 60.0  # GigaDepth's conv network per 1216 x 896 frame on a GPU; its UNet ablation 1 s


def sync(device: str) -> None:
    if device == "cuda":
        torch.cuda.synchronize()


def median_seconds(fn, repeats: int, warmup: int, device: str) -> float:
    """Median wall time of fn() over `repeats` calls after `warmup`, the device synchronised around each."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        sync(device)
        start = time.perf_counter()
        fn()
        sync(device)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


class GraphedBackbone(torch.nn.Module):
    """A backbone replayed from a CUDA graph captured for one input shape, precision and no_grad."""

    def __init__(self, backbone: torch.nn.Module, example: torch.Tensor, precision: str):
        super().__init__()
        self.static_in = example.clone()
        dtype = LOW_PRECISION.get(precision)

        def amp():  # no cast cache: the weight casts must be recorded in the graph, not reused from before
            return torch.autocast("cuda", dtype=dtype, enabled=dtype is not None, cache_enabled=False)

        stream = torch.cuda.Stream()
        stream.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(stream), torch.no_grad(), amp():
            for _ in range(3):  # warm-up outside the capture (cuDNN picks its algorithms)
                backbone(self.static_in)
        torch.cuda.current_stream().wait_stream(stream)
        self.graph = torch.cuda.CUDAGraph()
        with torch.no_grad(), amp(), torch.cuda.graph(self.graph):
            self.static_out = backbone(self.static_in)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        self.static_in.copy_(x)
        self.graph.replay()
        return self.static_out


def variant_backbone(model, variant: str, example: torch.Tensor, precision: str):
    """The model's backbone as `variant` runs it: eager, compile or cuda-graph."""
    if variant == "compile":
        return torch.compile(model.backbone)
    if variant == "cuda-graph":
        return GraphedBackbone(model.backbone, model.inputs(example), precision)
    return model.backbone


def disparity_agreement(low: np.ndarray, full: np.ndarray) -> dict:
    """How a reduced-precision disparity map differs from float32's: median and 99th percentile of
    |difference| (camera px) and the share of pixels off by more than 0.5 px or finite in one only."""
    both = np.isfinite(low) & np.isfinite(full)
    diff = np.abs(low - full)[both]
    return {"median_px": float(np.median(diff)), "p99_px": float(np.percentile(diff, 99)),
            "over_half_px": float(np.mean(diff > 0.5)),
            "finite_mismatch": float(np.mean(np.isfinite(low) != np.isfinite(full)))}


def inference_rows(name, model, ir_np, rig, device, precisions, variants, repeats, warmup) -> list[dict]:
    model = model.to(device).eval()
    float32 = predict_disparity(model, rig, ir_np, device)[0]
    x = torch.from_numpy(ir_np)[None, None].to(device)
    eager = model.backbone
    rows = []
    for precision in precisions:
        for variant in variants:
            model.backbone = variant_backbone(model, variant, x, precision)

            def forward(precision=precision):
                with torch.no_grad(), autocast(device, precision):
                    return model(x)

            seconds = median_seconds(forward, repeats, warmup, device)
            model.backbone = eager
            rows.append({"network": name, "precision": precision, "variant": variant, "ms": seconds * 1e3})
        # end to end as `dotsim infer` runs it: host copy, column -> disparity, edge-preserving upsampling
        seconds = median_seconds(lambda p=precision: predict_disparity(model, rig, ir_np, device, p),
                                 max(1, repeats // 10), 1, device)
        disparity = predict_disparity(model, rig, ir_np, device, precision)[0]
        rows.append({"network": name, "precision": precision, "variant": "predict_disparity (host)",
                     "ms": seconds * 1e3, "vs_float32": disparity_agreement(disparity, float32)})
    return rows


def inference_line(r: dict, published: bool) -> str:
    line = f"  {r['network']:<5} {r['precision']:<9} {r['variant']:<25} {r['ms']:10.2f} ms"
    if published:
        line += f"  {r['ms'] / PUBLISHED_MS:6.2f} x published"
    if r["precision"] != "float32" and "vs_float32" in r:
        line += ("  vs float32: median {median_px:.4f} px, p99 {p99_px:.3f} px, > 0.5 px {over_half_px:.4f}, "
                 "finite in one only {finite_mismatch:.4f}").format(**r["vs_float32"])
    return line


def training_row(cfg, batch, rig, device, precision, steps, warmup) -> dict:
    """ms per optimiser step (forward, backward, update; the batch already on the device) and peak
    memory, for the config's optimiser with `precision` autocast and, for float16, a gradient scaler."""
    torch.manual_seed(cfg.seed)
    model = build_model(cfg, rig).to(device).train()
    opt, _ = make_optimizer(model, cfg, steps_per_epoch=1)
    scaler = torch.amp.GradScaler(device, enabled=precision == "float16")
    batch = {k: v.to(device) for k, v in batch.items()}
    losses = []

    def step():
        with autocast(device, precision):
            loss, _ = batch_loss(model, batch, cfg)
        opt.zero_grad(set_to_none=True)
        scaler.scale(loss).backward()
        scaler.step(opt)
        scaler.update()
        losses.append(float(loss.detach()))

    if device == "cuda":
        torch.cuda.reset_peak_memory_stats()
    seconds = median_seconds(step, steps, warmup, device)
    peak = torch.cuda.max_memory_allocated() / 2**30 if device == "cuda" else float("nan")
    n = cfg.train.batch_size
    return {"precision": precision, "ms_per_step": seconds * 1e3, "samples_per_s": n / seconds,
            "peak_gib": peak, "finite": bool(np.all(np.isfinite(losses))), "first_loss": losses[0],
            "last_loss": losses[-1]}


def train_run(cfg, data, out, device, precision, steps) -> dict:
    """`steps` steps of train() (data loading, logging, checkpoints included) in `precision`."""
    d = cfg.to_dict()
    d["train"].update(max_steps=steps, amp=precision, checkpoint_every=10**9, image_every=10**9)
    run = out / f"run_{precision}"
    if (run / "checkpoint.pt").exists():
        (run / "checkpoint.pt").unlink()
    result = train(config_from_dict(d, "bench"), open_source(data, "train"), run, device=device,
                   progress=False)
    losses = np.array(result["losses"])
    k = max(1, min(10, len(losses) // 4))
    return {"precision": precision, "steps": len(losses), "seconds": result["seconds"],
            "samples_per_s": len(losses) * cfg.train.batch_size / result["seconds"],
            "finite": bool(np.all(np.isfinite(losses))), "mean_first": float(losses[:k].mean()),
            "mean_last": float(losses[-k:].mean()), "checkpoint": str(run / "checkpoint.pt")}


def profile_table(fn, device: str, runs: int, rows: int = 15) -> str:
    from torch.profiler import ProfilerActivity, profile

    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device == "cuda" else [])
    fn()
    with profile(activities=activities) as prof:
        for _ in range(runs):
            fn()
        sync(device)
    key = "self_device_time_total" if device == "cuda" else "self_cpu_time_total"
    return prof.key_averages().table(sort_by=key, row_limit=rows)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", choices=("cuda", "cpu"), default="cuda")
    parser.add_argument("--small", action="store_true",
                        help="train_tiny on 122 x 90 frames (a CPU check of the bench itself)")
    parser.add_argument("--config", help="training config (default: the published one, or tiny with --small)")
    parser.add_argument("--precisions", default=",".join(PRECISIONS), help="comma-separated, of " +
                        ", ".join(PRECISIONS))
    parser.add_argument("--backbones", default="conv,unet", help="comma-separated: conv, unet")
    parser.add_argument("--repeats", type=int, default=50, help="timed inference runs (median)")
    parser.add_argument("--warmup", type=int, default=5)
    parser.add_argument("--train-steps", type=int, default=20, help="timed training steps (median)")
    parser.add_argument("--train-run", type=int, default=0, metavar="N",
                        help="also train N steps with train() in float16 and bfloat16 (loss, NaN, samples/s)")
    parser.add_argument("--frames", type=int, default=8, help="training frames to render (2 per scene)")
    parser.add_argument("--compile", action="store_true", help="add torch.compile(backbone) rows")
    parser.add_argument("--cuda-graph", action="store_true", help="add CUDA-graph backbone rows (CUDA only)")
    parser.add_argument("--profile", action="store_true", help="torch.profiler: top ops of inference and "
                        "of a training step")
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch's default)")
    parser.add_argument("--out", default="out/bench_trainer_gpu", help="data, runs and results.json")
    args = parser.parse_args(argv)
    if args.device == "cuda" and not torch.cuda.is_available():
        print("bench.trainer_gpu skipped: no CUDA device (torch.cuda.is_available() is False); "
              "`--device cpu --small` checks the bench on CPU")
        return 0
    if args.threads:
        torch.set_num_threads(args.threads)
    device, out = args.device, Path(args.out) / ("small" if args.small else "published")
    precisions = [p for p in args.precisions.split(",") if p]
    if set(precisions) - set(PRECISIONS):
        parser.error(f"--precisions {args.precisions}: allowed {', '.join(PRECISIONS)}")
    graphs = args.cuda_graph and device == "cuda"
    if args.cuda_graph and not graphs:
        print("--cuda-graph: CUDA only, no graph rows on CPU")
    variants = ["eager"] + ["compile"] * args.compile + ["cuda-graph"] * graphs
    default_config = "dotsim/configs/train_tiny.toml" if args.small else "dotsim/configs/train_gigadepth.toml"
    cfg = load_config(args.config or default_config)
    scale = TINY_SCALE if args.small else 1.0
    info = {"device": torch.cuda.get_device_name() if device == "cuda" else "cpu", "torch": torch.__version__,
            "config": args.config or ("tiny" if args.small else "published"), "args": vars(args)}
    print(f"device {info['device']}, torch {torch.__version__}")

    data = out / "data"
    if not (data / "dataset.json").exists():
        print(f"rendering {args.frames} oracle frames at scale {scale:g} into {data} ...", flush=True)
        make_dataset(data, scenes=max(1, args.frames // 2), frames_per_scene=2, scale=scale, test_scenes=1)
    source = open_source(data, "train")
    frames, rig = source.frames, source.rig
    ds = FrameDataset(frames, rig, cfg.data, cfg.seed, augment=True)
    batch = next(iter(make_loader(ds, cfg.train.batch_size, 0, 0, 0)))
    pattern = generate_dot_pattern(rig.projector.width, rig.projector.height, seed=0).image.astype(np.float64)
    rng = np.random.default_rng(0)
    ir = synthetic_frame(random_depth(rig, rng), rig, pattern, rng)["ir"].astype(np.float32)
    cam = rig.camera
    results: dict = {"info": info}

    print(f"\ntraining, batch {cfg.train.batch_size} of {ds.crop_w}x{ds.crop_h} ({cam.width}x{cam.height} "
          f"frames), median of {args.train_steps} steps:", flush=True)
    results["training"] = []
    for precision in precisions:
        row = training_row(cfg, batch, rig, device, precision, args.train_steps, 2)
        results["training"].append(row)
        peak = f"{row['peak_gib']:.2f} GiB" if device == "cuda" else "n/a (CPU)"
        print(f"  {precision:<9} {row['ms_per_step']:9.1f} ms/step {row['samples_per_s']:8.2f} samples/s  "
              f"peak {peak}  loss {row['first_loss']:.3f} -> {row['last_loss']:.3f}"
              f"{'' if row['finite'] else '  NON-FINITE LOSS'}", flush=True)

    trained = None
    if args.train_run:
        print(f"\ntrain() for {args.train_run} steps ({len(frames)} frames, data loading included):")
        results["train_run"] = []
        for precision in ("float16", "bfloat16"):
            row = train_run(cfg, data, out, device, precision, args.train_run)
            results["train_run"].append(row)
            trained = row["checkpoint"]
            print(f"  {precision:<9} {row['steps']} steps in {row['seconds']:.1f} s, "
                  f"{row['samples_per_s']:.2f} samples/s, loss {row['mean_first']:.3f} -> "
                  f"{row['mean_last']:.3f} (means of the first / last steps)"
                  f"{'' if row['finite'] else ', NON-FINITE'}", flush=True)

    print(f"\ninference, one {cam.width}x{cam.height} frame, median of {args.repeats} after {args.warmup} "
          f"warm-up runs (published: {PUBLISHED_MS:g} ms for the conv network):")
    results["inference"] = []
    models = {}
    for backbone in [b for b in args.backbones.split(",") if b]:
        d = cfg.to_dict()
        d["model"]["backbone"] = backbone
        torch.manual_seed(0)
        if backbone == "conv" and trained:
            models[backbone] = load_model(trained, device)[0]
        else:
            models[backbone] = build_model(config_from_dict(d, f"--backbones {backbone}"), rig)
        rows = inference_rows(backbone, models[backbone], ir, rig, device, precisions, variants,
                              args.repeats, args.warmup)
        for r in rows:
            print(inference_line(r, published=r["network"] == "conv" and not args.small), flush=True)
        results["inference"] += rows

    if args.profile:
        model = models.get("conv") or next(iter(models.values()))
        x = torch.from_numpy(ir)[None, None].to(device)
        for precision in precisions:
            def forward(precision=precision):
                with torch.no_grad(), autocast(device, precision):
                    model(x)

            print(f"\nprofile: inference, {precision}, 5 runs\n" + profile_table(forward, device, 5))
        model.train()
        opt = torch.optim.SGD(model.parameters(), lr=1e-6)
        on_device = {k: v.to(device) for k, v in batch.items()}
        amp = cfg.train.amp

        def step():
            with autocast(device, amp):
                loss, _ = batch_loss(model, on_device, cfg)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()

        print(f"\nprofile: training step (amp {amp}), 3 steps\n" + profile_table(step, device, 3))

    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(results, indent=1))
    conv = {r["precision"]: r["ms"] for r in results["inference"] if r["network"] == "conv"
            and r["variant"] == "eager"}
    print(f"\nsummary ({info['device']}): conv network "
          + ", ".join(f"{p} {ms:.1f} ms" for p, ms in conv.items())
          + f" per frame against the published {PUBLISHED_MS:g} ms; training "
          + ", ".join(f"{r['precision']} {r['samples_per_s']:.1f} samples/s" for r in results["training"])
          + f"; results in {out / 'results.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
