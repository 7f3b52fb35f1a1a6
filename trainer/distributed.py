"""Data-parallel training over several processes: joining the process group, and launching one.

A run with N processes ("ranks") is the same optimisation as a run with one: `[train].batch_size` is the
global batch, each rank takes batch_size / N of its samples (trainer/samples.py), the loss is normalised by
the global batch (trainer/train.py) and BatchNorm uses global batch statistics (trainer/model.py), so
the ranks only change the speed. torchrun (or `dotsim train --nproc N`, which calls run_on_ranks) puts
RANK, LOCAL_RANK, WORLD_SIZE, MASTER_ADDR and MASTER_PORT in each process's environment;
join_process_group reads them.
"""

from __future__ import annotations

import logging
import os
import pickle
import socket
import sys
from dataclasses import dataclass

import torch
import torch.distributed as dist
import torch.multiprocessing as mp

from dotsim.process_lifetime import die_with_parent, stop_processes
from trainer.samples import DataError


@dataclass(frozen=True)
class Ranks:
    """This process's place among the training processes; rank 0 of 1 when not launched as several."""

    rank: int = 0
    world: int = 1
    device: str = "cpu"

    @property
    def main(self) -> bool:
        """Rank 0 alone writes checkpoints and TensorBoard and prints progress."""
        return self.rank == 0

    def mean(self, values: torch.Tensor) -> torch.Tensor:
        """The mean of `values` over all ranks (every rank gets it)."""
        if self.world == 1:
            return values
        total = values.to(self.device, copy=True)
        dist.all_reduce(total)
        return total.to(values.device) / self.world


ONE_PROCESS = Ranks()


def join_process_group(device: str) -> Ranks:
    """Join the process group the environment describes: gloo on CPU, NCCL on CUDA with one GPU per local
    rank. Without WORLD_SIZE (or with 1) this is a single process and nothing is joined."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world == 1:
        return Ranks(device=device)
    rank, local = int(os.environ["RANK"]), int(os.environ.get("LOCAL_RANK", os.environ["RANK"]))
    if device == "cuda":
        if local >= torch.cuda.device_count():
            raise DataError(f"--device cuda: local rank {local} needs a GPU of its own; "
                            f"{torch.cuda.device_count()} visible")
        device = f"cuda:{local}"
        torch.cuda.set_device(device)
    dist.init_process_group("nccl" if device.startswith("cuda") else "gloo", rank=rank, world_size=world)
    return Ranks(rank, world, device)


def leave_process_group(ranks: Ranks) -> None:
    if ranks.world > 1:
        dist.destroy_process_group()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _rank_main(rank: int, launcher: int, env: dict, threads: int, fn, args, kwargs, outcomes) -> None:
    die_with_parent(launcher)  # a launcher killed outright takes its ranks with it
    os.environ.update(env, RANK=str(rank), LOCAL_RANK=str(rank))
    torch.set_num_threads(threads)
    # pickled here: torch's queue would share tensors through this process's memory, gone once it exits
    try:
        value = fn(*args, **kwargs)
    except Exception as e:
        outcomes.put(pickle.dumps((e, None)))  # the launcher re-raises it: an expected error stays one line
        raise
    if rank == 0:
        outcomes.put(pickle.dumps((None, value)))
    # Done and reported: leave without the interpreter's teardown, where destroying gloo's connection
    # threads aborted a finished rank now and then ("terminate called without an active exception",
    # SIGABRT after the test's last collective), turning a finished run into a failed one.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


def run_on_ranks(nproc: int, fn, *args, **kwargs):
    """Run fn(*args, **kwargs) in `nproc` local processes that form one process group, as torchrun
    would, and return rank 0's result. The CPU threads are shared out among the processes. When a rank
    raises, the others are stopped and the first exception reported is raised here. Ctrl-C, SIGTERM or
    SIGHUP here (dotsim.process_lifetime.stop_signals) stops every rank; a launcher killed outright
    takes them with it (each dies with its parent)."""
    env = {"MASTER_ADDR": "127.0.0.1", "MASTER_PORT": str(_free_port()), "WORLD_SIZE": str(nproc)}
    threads = max(1, torch.get_num_threads() // nproc)
    outcomes = mp.get_context("spawn").SimpleQueue()
    ranks = mp.start_processes(_rank_main, args=(os.getpid(), env, threads, fn, args, kwargs, outcomes),
                               nprocs=nproc, join=False, start_method="spawn")
    received = []

    def drain() -> None:  # as we go: a rank writing into a full pipe would wait for ever
        while not outcomes.empty():
            received.append(pickle.loads(outcomes.get()))

    # torch warns of each rank it stops after another failed; the failure itself is what we report
    logging.getLogger("torch.multiprocessing.spawn").setLevel(logging.ERROR)
    try:
        while not ranks.join(timeout=0.1):
            drain()
    except (mp.ProcessRaisedException, mp.ProcessExitedException):
        drain()
        errors = [e for e, _ in received if e is not None]
        if errors:
            raise errors[0] from None
        raise
    except BaseException:  # Ctrl-C, a stop signal: no rank goes on alone
        stop_processes(ranks.processes)
        raise
    drain()
    return next(value for e, value in received if e is None)
