"""Data-parallel training throughput on CPU: samples/s of one process against N gloo ranks on the same
threads, the same config and data (the tiny oracle dataset of tests/trainer_fixtures.py).

    python -m bench.trainer_ddp [--config configs/train_tiny.toml] [--nproc 2] [--threads 2] [--steps 40]

One process gets all --threads; each of the N ranks gets threads / N (as `dotsim train --nproc` shares
them out). [train].batch_size is the global batch in both. Time is the training loop's (start-up of the
processes and the data listing excluded); each is measured twice, alternating, and the better one kept.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import torch

from trainer.config import load_config
from trainer.distributed import run_on_ranks
from trainer.train import train

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from trainer_fixtures import make_dataset  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default="configs/train_tiny.toml")
    parser.add_argument("--nproc", type=int, default=2)
    parser.add_argument("--threads", type=int, default=2, help="CPU threads in all (default 2)")
    parser.add_argument("--steps", type=int, default=40, help="optimiser steps per measurement")
    args = parser.parse_args(argv)
    cfg = load_config(args.config)
    cfg = replace(cfg, train=replace(cfg.train, max_steps=args.steps, checkpoint_every=10**9,
                                     image_every=10**9, epochs=10**6))
    torch.set_num_threads(args.threads)
    best = {1: 0.0, args.nproc: 0.0}
    with tempfile.TemporaryDirectory() as tmp:
        data = make_dataset(Path(tmp) / "ds", scenes=8, frames_per_scene=2)
        for repeat in range(2):
            for nproc in best:
                out = Path(tmp) / f"run{nproc}_{repeat}"
                if nproc == 1:
                    result = train(cfg, data, out, progress=False)
                else:
                    result = run_on_ranks(nproc, train, cfg, data, out, progress=False)
                rate = args.steps * cfg.train.batch_size / result["seconds"]
                print(f"{nproc} process(es): {rate:.1f} samples/s ({result['seconds']:.1f} s)", flush=True)
                best[nproc] = max(best[nproc], rate)
    print(f"summary ({args.config}, batch {cfg.train.batch_size}, {args.threads} threads in all): "
          + ", ".join(f"{n} process(es) {r:.1f} samples/s" for n, r in best.items())
          + f"; ratio {best[args.nproc] / best[1]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
