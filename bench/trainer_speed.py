"""Trainer speed on CPU: inference per 1216 x 896 frame (tiny and published networks) against StereoSGBM
on the same frame, and training samples per second of the tiny network.

    python -m bench.trainer_speed [--repeats 5] [--no-published] [--threads N]

The frame is an oracle-rendered Structure Core frame (dotsim/oracle_dataset.py): a tilted wall and boxes.
Networks have random weights (speed does not depend on training; routing spreads pixels over the
classes). Prints medians over --repeats runs and the ratios to SGBM.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

from dotsim.frame_source import open_source
from dotsim.oracle_dataset import make_dataset, random_depth, synthetic_frame
from dotsim.patterns import generate_dot_pattern
from dotsim.rig.geometry import reference_image
from dotsim.rig.presets import get_preset
from trainer.checkpoint import predict_disparity
from trainer.config import load_config
from trainer.model import build_model
from trainer.sgbm import num_disparities_for, sgbm_disparity
from trainer.train import batch_loss


def median_seconds(fn, repeats: int) -> float:
    fn()  # warm-up (allocator, one-time initialisations)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--no-published", action="store_true", help="skip the 377 M parameter network")
    parser.add_argument("--threads", type=int, default=1,
                        help="torch CPU threads (default 1: on the shared 2-core machine 2 threads were "
                        "slower and far noisier)")
    parser.add_argument("--train-steps", type=int, default=10, help="steps timed for samples/s")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)

    rig = get_preset("structure_core")
    print(f"making a {rig.camera.width}x{rig.camera.height} frame and the reference image ...", flush=True)
    pattern = generate_dot_pattern(rig.projector.width, rig.projector.height, seed=0).image.astype(np.float64)
    rng = np.random.default_rng(0)
    depth = random_depth(rig, rng)
    ir = synthetic_frame(depth, rig, pattern, rng)["ir"].astype(np.float32)
    reference = reference_image(pattern, rig, supersample=2)
    n_disp = num_disparities_for(rig, float(np.nanmin(depth)))  # the range this frame's depths need

    results = {"StereoSGBM": median_seconds(lambda: sgbm_disparity(ir, reference, n_disp), args.repeats)}
    configs = {"tiny": "dotsim/configs/train_tiny.toml"}
    if not args.no_published:
        configs["published (377 M)"] = "dotsim/configs/train_gigadepth.toml"
    for name, path in configs.items():
        cfg = load_config(path)
        torch.manual_seed(0)
        model = build_model(cfg, rig)
        results[f"network {name}"] = median_seconds(lambda m=model: predict_disparity(m, rig, ir),
                                                    args.repeats)
        del model

    sgbm = results["StereoSGBM"]
    print(f"\ninference per {rig.camera.width}x{rig.camera.height} frame, CPU, {args.threads} thread(s), "
          f"median of {args.repeats}:")
    for name, s in results.items():
        print(f"  {name:<28} {s * 1000:9.1f} ms   {s / sgbm:6.2f} x SGBM")

    # training throughput of the tiny network on its own crops (tiny rig, as in the tests)
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        from trainer.samples import FrameDataset, make_loader

        data = make_dataset(Path(tmp) / "ds", scenes=4, frames_per_scene=2)
        cfg = load_config("dotsim/configs/train_tiny.toml")
        source = open_source(data, "train")
        frames, small_rig = source.frames, source.rig
        ds = FrameDataset(frames, small_rig, cfg.data, cfg.seed, augment=True)
        batch = next(iter(make_loader(ds, cfg.train.batch_size, 0, 0, 0)))
        model = build_model(cfg, small_rig)
        opt = torch.optim.Adam(model.parameters(), cfg.train.lr)

        def step():
            loss, _ = batch_loss(model, batch, cfg)
            opt.zero_grad()
            loss.backward()
            opt.step()

        per_step = median_seconds(step, args.train_steps)
        cam = small_rig.camera
        print(f"\ntraining, tiny network, {ds.crop_w}x{ds.crop_h} crops of a {cam.width}x{cam.height} rig, "
              f"batch {cfg.train.batch_size}: {per_step * 1000:.1f} ms/step (median of {args.train_steps}), "
              f"{cfg.train.batch_size / per_step:.1f} samples/s")
    print(f"summary: SGBM {sgbm * 1000:.0f} ms/frame; " + ", ".join(
        f"{k} {v * 1000:.0f} ms ({v / sgbm:.1f}x)" for k, v in results.items() if k != "StereoSGBM"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
