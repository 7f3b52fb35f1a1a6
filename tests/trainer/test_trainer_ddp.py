"""Data-parallel training: 2 real CPU processes joined with gloo train as one process with the same
global batch does, resume across process counts, rank 0 alone writes and prints."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.distributed as dist
from torch import nn

from commands.cli import main
from dotsim.frame_source import open_source
from dotsim.oracle_dataset import make_dataset
from trainer.checkpoint import load_checkpoint
from trainer.config import config_from_dict, load_config
from trainer.distributed import Ranks, leave_process_group, run_on_ranks
from trainer.model import GlobalBatchNorm2d
from trainer.samples import EpochSampler
from trainer.train import train

ROOT = Path(__file__).resolve().parents[2]


pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("ds"), scenes=3, frames_per_scene=2)


def tiny_config(steps: int, batch_size: int = 4):
    """train_tiny on 64 x 48 crops, with SGD: Adam divides each gradient by its own running size, so
    the rounding noise of a summation order (one process or two) in near-zero gradients becomes
    full-size steps, and the runs part after a step or two for that reason alone (measured on 122 x 90
    frames: 5e-6 at step 2, 4e-5 at step 3, against 2e-7 with SGD)."""
    d = load_config(ROOT / "dotsim/configs/train_tiny.toml").to_dict()
    d["data"].update(crop_width=64, crop_height=48)
    d["train"].update(max_steps=steps, batch_size=batch_size, checkpoint_every=1000, image_every=2,
                      log_every=1, optimizer="sgd", lr=0.05)
    return config_from_dict(d, "test config")


def tiny_config_file(path: Path, steps: int, batch_size: int) -> Path:
    text = (ROOT / "dotsim/configs/train_tiny.toml").read_text()
    values = {"crop_width": 64, "crop_height": 48, "max_steps": steps, "batch_size": batch_size}
    lines = [next((f"{k} = {v}" for k, v in values.items() if line.startswith(f"{k} =")), line)
             for line in text.splitlines()]
    path.write_text("\n".join(lines))
    return path


def test_ranks_share_each_global_batch_and_together_see_what_one_process_sees():
    n, batch, skip = 23, 6, 6  # 3 whole batches of 6; resumed after the first
    one = list(EpochSampler(n, seed=5, epoch=2, skip=skip, batch=batch))
    assert len(one) == 12 and len(set(one)) == 12
    shares = [list(EpochSampler(n, 5, 2, skip, batch, rank=r, world=3)) for r in range(3)]
    assert [len(s) for s in shares] == [4, 4, 4]
    for k in range(2):  # batch k of each rank (2 samples) together = the single process's batch k
        assert sorted(sum((s[2 * k : 2 * k + 2] for s in shares), [])) == sorted(one[6 * k : 6 * k + 6])
    assert shares == [list(EpochSampler(n, 5, 2, skip, batch, r, 3)) for r in range(3)]  # deterministic
    assert list(EpochSampler(n, seed=5, epoch=3, batch=batch)) != list(EpochSampler(n, 5, 2, 0, batch))


def _batchnorm_on_halves(bn_state: dict, x: torch.Tensor, grad_out: torch.Tensor) -> dict:
    """Each rank's half of the batch through GlobalBatchNorm2d ("global") and nn.BatchNorm2d ("per_rank"):
    all ranks' outputs and input gradients, the parameter gradients summed over the ranks (DDP's average
    times the ranks) and rank 0's running statistics."""
    rank, world = int(os.environ["RANK"]), int(os.environ["WORLD_SIZE"])
    dist.init_process_group("gloo", rank=rank, world_size=world)
    results = {}
    for kind, cls in (("global", GlobalBatchNorm2d), ("per_rank", nn.BatchNorm2d)):
        bn = cls(x.shape[1])
        bn.load_state_dict(bn_state)
        part = x.chunk(world)[rank].clone().requires_grad_(True)
        out = bn(part)
        out.backward(grad_out.chunk(world)[rank])
        got = {}
        for name, t in {"out": out.detach(), "grad_x": part.grad}.items():
            pieces = [torch.empty_like(t) for _ in range(world)]
            dist.all_gather(pieces, t.contiguous())
            got[name] = torch.cat(pieces)
        for name, t in {"grad_w": bn.weight.grad, "grad_b": bn.bias.grad}.items():
            dist.all_reduce(t)
            got[name] = t
        got["running_mean"], got["running_var"] = bn.running_mean, bn.running_var
        results[kind] = got
    leave_process_group(Ranks(rank, world, "cpu"))
    return results


def test_global_batchnorm_on_two_ranks_equals_torch_batchnorm_on_the_whole_batch():
    g = torch.Generator().manual_seed(0)
    x = torch.randn(4, 3, 5, 6, generator=g) * 2 + 3
    x[2:] += 1.5  # the two halves' statistics differ, so per-rank statistics cannot pass
    grad_out = torch.randn(x.shape, generator=g)
    reference = nn.BatchNorm2d(3)
    with torch.no_grad():
        reference.weight.uniform_(0.5, 1.5, generator=g)
        reference.bias.uniform_(-0.5, 0.5, generator=g)
    state = {k: v.clone() for k, v in reference.state_dict().items()}
    whole = x.clone().requires_grad_(True)
    out = reference(whole)
    out.backward(grad_out)
    expected = {"out": out.detach(), "grad_x": whole.grad, "grad_w": reference.weight.grad,
                "grad_b": reference.bias.grad, "running_mean": reference.running_mean,
                "running_var": reference.running_var}
    got = run_on_ranks(2, _batchnorm_on_halves, state, x, grad_out)
    for name, value in expected.items():
        torch.testing.assert_close(got["global"][name], value, rtol=1e-5, atol=1e-6, msg=name)
    assert not torch.allclose(got["per_rank"]["out"], expected["out"], atol=1e-3)


def test_two_ranks_train_as_one_process_and_resume_across_process_counts(data, tmp_path):
    """2 ranks x 2 samples give the losses of 1 process x 4; a 2-rank checkpoint resumes in one process
    and that one on 2 ranks again, continuing the single process's run.

    Tolerances, measured: the first 3 steps agree to 3e-7 (relative; with SGD, tiny_config); BatchNorm
    with per-rank statistics instead of global ones is off by 6e-5, 3e-5 and 2e-4 there (measured with
    Adam on 128 x 94 frames). Later steps drift apart as any change of summation order makes them drift;
    1 vs 2 CPU threads in one process differ by 6e-6 at step 4 and 1.5e-5 at step 5."""
    one = train(tiny_config(6), open_source(data, "train"), tmp_path / "one", progress=False)["losses"]
    run = tmp_path / "ddp"
    first = run_on_ranks(2, train, tiny_config(3), open_source(data, "train"), run, progress=False)
    assert first["step"] == 3
    np.testing.assert_allclose(first["losses"], one[:3], rtol=2e-6)
    assert sorted(p.name for p in run.iterdir()) == ["checkpoint.pt", "tb"]
    assert len(list((run / "tb").iterdir())) == 1  # one SummaryWriter: rank 0's
    assert load_checkpoint(run / "checkpoint.pt")[0]["step"] == 3

    second = train(tiny_config(5), open_source(data, "train"), run, resume=True, progress=False)["losses"]
    third = run_on_ranks(2, train, tiny_config(6), open_source(data, "train"), run, resume=True,
                         progress=False)["losses"]
    np.testing.assert_allclose(second + third, one[3:], rtol=1e-4)
    assert one[0] != one[1]


def test_nproc_that_does_not_divide_the_batch_is_a_one_line_error(data, tmp_path, capfd):
    cfg = tiny_config_file(tmp_path / "cfg.toml", steps=2, batch_size=3)
    status = main(["train", "--config", str(cfg), "--data", str(data), "--out", str(tmp_path / "run"),
                   "--nproc", "2"])
    captured = capfd.readouterr()
    assert status == 1 and captured.out == ""
    assert captured.err.strip().splitlines() == [
        "dotsim train: error: [train].batch_size 3 is the global batch and must divide evenly among "
        "the 2 processes"]
    assert not (tmp_path / "run").exists()
    with pytest.raises(SystemExit) as refused:  # by the parser, before anything runs
        main(["train", "--config", str(cfg), "--data", str(data), "--out", str(tmp_path / "run"),
              "--nproc", "0"])
    assert refused.value.code == 2
    assert capfd.readouterr().err.strip().splitlines()[-1] == (
        "dotsim train: error: argument --nproc: '0': allowed: an integer >= 1")


def test_torchrun_two_processes_rank_zero_alone_prints_and_writes(data, tmp_path):
    cfg = tiny_config_file(tmp_path / "cfg.toml", steps=2, batch_size=4)
    run = tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
         "-m", "commands.cli", "train", "--config", str(cfg), "--data", str(data), "--out", str(run)],
        capture_output=True, text=True, cwd=ROOT, env={**os.environ, "OMP_NUM_THREADS": "1"}, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    summaries = [line for line in proc.stdout.splitlines() if line.startswith("trained ")]
    assert len(summaries) == 1 and "to step 2/2" in summaries[0] and "on 2 process(es)" in summaries[0]
    assert load_checkpoint(run / "checkpoint.pt")[0]["step"] == 2
    assert len(list((run / "tb").iterdir())) == 1
