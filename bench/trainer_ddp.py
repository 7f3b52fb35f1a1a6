"""Data-parallel training throughput on CPU: samples/s of one process against N gloo ranks on the same
threads, the same config and data (the tiny oracle dataset of dotsim/oracle_dataset.py).

    python -m bench.trainer_ddp [--config train_tiny] [--nproc 2] [--threads 2] [--steps 40]

Measured: one process on all --threads, one process on threads / N, and N ranks on threads / N each
(as `dotsim train --nproc` shares them out); [train].batch_size is the global batch in all three. Time is
the training loop's (start-up of the processes and the data listing excluded); each is measured twice,
alternating, and the better one kept.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import torch

from dotsim.frame_source import open_source
from dotsim.oracle_dataset import make_dataset
from trainer.config import load_config
from trainer.distributed import run_on_ranks
from trainer.train import train


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default="dotsim/configs/train_tiny.toml")
    parser.add_argument("--nproc", type=int, default=2)
    parser.add_argument("--threads", type=int, default=2, help="CPU threads in all (default 2)")
    parser.add_argument("--steps", type=int, default=40, help="optimiser steps per measurement")
    args = parser.parse_args(argv)
    cfg = load_config(args.config)
    cfg = replace(cfg, train=replace(cfg.train, max_steps=args.steps, checkpoint_every=10**9,
                                     image_every=10**9, epochs=10**6))
    per_rank = max(1, args.threads // args.nproc)
    # (processes, threads each): one process on all threads, one on a rank's share, the N ranks
    setups = list(dict.fromkeys([(1, args.threads), (1, per_rank), (args.nproc, per_rank)]))
    best = dict.fromkeys(setups, 0.0)
    with tempfile.TemporaryDirectory() as tmp:
        data = open_source(make_dataset(Path(tmp) / "ds", scenes=8, frames_per_scene=2), "train")
        for repeat in range(2):
            for nproc, threads in setups:
                out = Path(tmp) / f"run{nproc}_{threads}_{repeat}"
                if nproc == 1:
                    torch.set_num_threads(threads)
                    result = train(cfg, data, out, progress=False)
                else:
                    torch.set_num_threads(args.threads)  # run_on_ranks shares these out
                    result = run_on_ranks(nproc, train, cfg, data, out, progress=False)
                rate = args.steps * cfg.train.batch_size / result["seconds"]
                print(f"{nproc} process(es) x {threads} thread(s): {rate:.1f} samples/s "
                      f"({result['seconds']:.1f} s)", flush=True)
                best[nproc, threads] = max(best[nproc, threads], rate)
    print(f"summary ({args.config}, global batch {cfg.train.batch_size}, best of 2): " + ", ".join(
        f"{n} process(es) x {t} thread(s) {r:.1f} samples/s" for (n, t), r in best.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
