"""The training loop: teacher-forced tree losses, checkpoints with exact resume, TensorBoard logging.

RUN/checkpoint.pt holds everything a resume needs (trainer/checkpoint.py writes and reads it); RUN/tb/
the TensorBoard scalars and images. Given the same config, data and seed a CPU run is
deterministic, and a resumed run continues with the losses an unbroken run would have had.
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import random
import sys
import threading
import time
from functools import partial
from pathlib import Path

import numpy as np
import torch
from torch.nn.parallel import DistributedDataParallel
from tqdm import tqdm

from dotsim.file_io import DiskFullError, disk_full_error, is_disk_full, make_folder
from dotsim.frame_source import FrameSource, SourceError
from dotsim.rig.geometry import Rig
from trainer.checkpoint import CHECKPOINT, TrainingState, check_rig, restore_checkpoint, save_checkpoint
from trainer.config import Config, resolution_mismatch
from trainer.distributed import ONE_PROCESS, Ranks, join_process_group, leave_process_group
from trainer.model import GigaDepthNet, autocast, build_model
from trainer.samples import DataError, FrameDataset, make_loader
from trainer.scoring import Validation


def keep_freed_memory() -> None:
    """Have glibc's malloc keep the memory a step frees for the next step, instead of handing it back
    to the system (for the rest of the process). Every step frees and allocates again the gradients of
    the per-line weight tables (33 MB each in train_table2) and the activations; above its mmap
    threshold glibc maps fresh pages for each, which the kernel zeroes on first touch: 300 one-thread
    steps of train_table2 spent 19.7 of their 155 s in the kernel, 4.8 s with this (docs/TRAINER.md
    "Speed"). Elsewhere than glibc (no libc.so.6, no mallopt) it does nothing."""
    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):
        return
    m_trim_threshold, m_mmap_max = -1, -4  # glibc's malloc.h
    mallopt(m_mmap_max, 0)                 # every block from the heap, none mapped on its own
    mallopt(m_trim_threshold, 2**31 - 1)   # and the heap's free top kept, not trimmed


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def batch_loss(model: GigaDepthNet, batch: dict, cfg: Config, ranks: Ranks = ONE_PROCESS,
               weights: tuple[float, float] | None = None) -> tuple[torch.Tensor, dict[str, float]]:
    """Weighted loss of one batch: sum_l ce_weights[l] * CE_l + l1_weight * L1, each the mean over the
    valid pixels weighted by 1 + edge_weight * edge (GigaDepth weights edges up: the column jumps there).
    weights: (l1_weight, edge_weight) at this step (loss_weights; None: the config's constants).

    With several ranks each holds part of the global batch; the means are over the global batch's pixel
    weight (times the number of ranks, as DDP averages the ranks' gradients), so the ranks' mean loss and
    gradient are the single-process ones."""
    feat = model.features(batch["ir"])
    valid = batch["valid"] & model.in_range(batch["row0"], batch["x0"], batch["column"])
    terms = model.loss_terms(feat, batch["row0"], batch["column"], valid, batch["x0"])
    l1_weight, edge_weight = weights or (cfg.train.l1_weight, cfg.train.edge_weight)
    weight = 1.0 + edge_weight * batch["edge"][valid]
    norm = ranks.mean(weight.sum()).clamp_min(1.0 / ranks.world)
    parts = {f"ce{k + 1}": (ce * weight).sum() / norm for k, ce in enumerate(terms["ce"])}
    parts["l1"] = (terms["l1"] * weight).sum() / norm
    loss = sum(w * parts[f"ce{k + 1}"] for k, w in enumerate(cfg.train.ce_weights))
    loss = loss + l1_weight * parts["l1"]
    return loss, {k: float(v.detach()) for k, v in parts.items()}


class TrainingLoss(torch.nn.Module):
    """batch_loss as a module: DDP synchronises the gradients of what runs through its module's forward."""

    def __init__(self, model: GigaDepthNet, cfg: Config, ranks: Ranks):
        super().__init__()
        self.model, self.cfg, self.ranks = model, cfg, ranks

    def forward(self, batch: dict, weights: tuple[float, float] | None = None
                ) -> tuple[torch.Tensor, dict[str, float]]:
        return batch_loss(self.model, batch, self.cfg, self.ranks, weights)


def run_share(step: int, total_steps: int) -> float:
    """The share of a run of `total_steps` done at `step`, in [0, 1]."""
    return min(step, total_steps) / max(total_steps, 1)


def piece(values: tuple[float, ...], done: float) -> float:
    """The value of `values` in force at share `done` of a run, each for an equal share of it.

    >>> [piece((1.0, 0.5), done) for done in (0.0, 0.49, 0.5, 1.0)]
    [1.0, 1.0, 0.5, 0.5]
    """
    return values[min(int(done * len(values)), len(values) - 1)]


def lr_factor(cfg: Config, step: int, total_steps: int) -> float:
    """The factor on [train].lr at `step` of a run of `total_steps` (cosine and piecewise schedules; step
    decay is torch's StepLR)."""
    t = cfg.train
    done = run_share(step, total_steps)
    if t.lr_schedule == "cosine":
        return t.lr_final + (1 - t.lr_final) * 0.5 * (1 + math.cos(math.pi * done))
    return piece(t.lr_factors, done)


def loss_weights(cfg: Config, step: int, total_steps: int) -> tuple[float, float]:
    """(l1_weight, edge_weight) for the step after `step` of a run of `total_steps`: [train] l1_weight, or
    its linear ramp to l1_weight_end; edge_weight, or the edge_weights ramp (GigaDepth's schedules)."""
    t = cfg.train
    done = run_share(step, total_steps)
    l1 = t.l1_weight + (t.l1_weight_end - t.l1_weight) * done if t.l1_weight_end > 0 else t.l1_weight
    return l1, piece(t.edge_weights, done) if t.edge_weights else t.edge_weight


def make_optimizer(model: torch.nn.Module, cfg: Config, steps_per_epoch: int, total_steps: int = 1):
    """The optimiser and its learning-rate schedule over a run of total_steps."""
    t = cfg.train
    if t.optimizer == "sgd":
        opt = torch.optim.SGD(model.parameters(), lr=t.lr, momentum=t.momentum, weight_decay=t.weight_decay)
    else:
        # Adam updates every table entry each step, though a batch touches few: the plain per-tensor
        # loop measured 47 ms per step for train_cpu's 8.3 M parameters on 2 CPU threads, fused 4.8 ms.
        opt = torch.optim.Adam(model.parameters(), lr=t.lr, weight_decay=t.weight_decay, fused=True)
    if t.lr_schedule == "step":
        sched = torch.optim.lr_scheduler.StepLR(opt, step_size=max(1, t.lr_step_epochs * steps_per_epoch),
                                                gamma=t.lr_gamma)
    else:
        sched = torch.optim.lr_scheduler.LambdaLR(opt, partial(lr_factor, cfg, total_steps=total_steps))
    return opt, sched


@contextlib.contextmanager
def disk_full_in(run_dir: str | Path):
    """Around a training run: a full disk under the run folder that a library reports as a plain
    OSError (TensorBoard's event file, written by a thread of its own) becomes the one-line
    DiskFullError every dotsim command prints. Checkpoints are written atomically, so the last good
    one stays."""
    previous = threading.excepthook

    def quiet(args) -> None:  # TensorBoard's writer thread: its error is raised again in this one
        if not is_disk_full(args.exc_value):
            previous(args)

    threading.excepthook = quiet
    try:
        yield
    except DiskFullError:
        raise
    except OSError as error:
        if not is_disk_full(error):
            raise
        raise disk_full_error(Path(error.filename or Path(run_dir) / "tb"), None) from None
    finally:
        threading.excepthook = previous
        for bar in list(tqdm._instances):  # the message starts a line of its own, not the bar's
            bar.close()


def _log_images(writer, step: int, model: GigaDepthNet, batch: dict) -> None:
    """IR, GT column, predicted column and |error| (leaf units, 0..5) of the first sample."""
    was_training = model.training
    model.eval()
    with torch.no_grad():
        pred = model(batch["ir"][:1], batch["row0"][:1], batch["x0"][:1])[0].float()
    model.train(was_training)
    ir = batch["ir"][0, 0]
    writer.add_image("ir", (ir / ir.max().clamp_min(1e-6)).clamp(0, 1)[None], step)
    valid = batch["valid"][0]
    gt = torch.where(valid, batch["column"][0], torch.zeros_like(pred))
    lo, hi = gt[valid].min() if valid.any() else 0, gt[valid].max() if valid.any() else 1
    scale = lambda x: ((x - lo) / max(float(hi - lo), 1e-6)).clamp(0, 1)[None]  # noqa: E731
    writer.add_image("column_gt", scale(gt), step)
    writer.add_image("column_pred", scale(pred), step)
    err = ((pred - gt).abs() * model.leaves * (1 - 2 * model.cfg.column_padding) / 5).clamp(0, 1) * valid
    writer.add_image("error_leaves_0_to_5", err[None], step)


def train(cfg: Config, data: FrameSource, out_dir: str | Path, resume: bool = False,
          device: str = "cpu", progress: bool = True, max_seconds: float = 0.0,
          validation: FrameSource | None = None, val_frames: int = 4, progress_bar: bool = True) -> dict:
    """Train on the frames of `data` (dotsim.frame_source.open_source) into out_dir; returns {"step",
    "losses" (per step), "seconds", "validation" (the last validation's rates, {} without validation)}.

    Launched as several processes (torchrun, or trainer.distributed.run_on_ranks), each is one DDP rank
    of the same run: each takes its share of every global batch, and rank 0 alone writes and prints.
    max_seconds > 0 stops (with a checkpoint) after the first step that ends past that wall time.
    validation: `val_frames` frames spread over that source (held out from the training frames) are
    scored every [train].val_every steps and at the end (trainer.scoring.Validation), into TensorBoard.
    progress: print warnings and the summary, with a progress bar (progress_bar=False: without)."""
    out_dir, t, rig = Path(out_dir), cfg.train, data.rig
    steps_per_epoch, total_steps = plan_steps(cfg, data)
    ranks = join_ranks(cfg, rig, device, progress)
    keep_freed_memory()
    validate = held_out_validation(validation, val_frames, data) if ranks.main else None
    seed_everything(cfg.seed)
    state = new_state(cfg, rig, ranks.device, steps_per_epoch, total_steps)
    step = restore_checkpoint(out_dir / CHECKPOINT, resume, state, cfg, rig, data.name)
    loss_of = TrainingLoss(state.model, cfg, ranks)
    if ranks.world > 1:  # BatchNorm statistics are global already (GlobalBatchNorm2d): no buffers to send
        loss_of = DistributedDataParallel(loss_of, forward_sync_buffers=False)
    ds = FrameDataset(data.frames, rig, cfg.data, cfg.seed, augment=True, stride=cfg.model.stride)
    progress = progress and ranks.main
    pattern = stored_pattern(data, progress)
    losses, rates, start = [], {}, time.perf_counter()
    state.model.train()
    bar = tqdm(total=total_steps, initial=step, desc="train", unit="step",
               disable=not (progress and progress_bar))
    with tensorboard_log(out_dir, step, ranks.main) as writer:
        while step < total_steps:
            epoch, within = divmod(step, steps_per_epoch)
            for batch in make_loader(ds, t.batch_size, epoch, within * t.batch_size, cfg.data.workers,
                                     ranks.rank, ranks.world):
                batch = {k: v.to(ranks.device) for k, v in batch.items()}
                weights = loss_weights(cfg, step, total_steps)
                value, parts, elapsed = optimiser_step(loss_of, state, batch, cfg, ranks, step, start,
                                                       weights)
                step += 1
                losses.append(value)
                bar.update(1)
                bar.set_postfix(loss=f"{value:.4f}", epoch=epoch)
                out_of_time = 0 < max_seconds < elapsed
                if ranks.main:  # rank 0 alone writes
                    rates = log_step(writer, step, step == total_steps, out_of_time, cfg, state, value, parts,
                                     batch, validate, ranks.device) or rates
                    if step % t.checkpoint_every == 0 or step == total_steps or out_of_time:
                        save_checkpoint(out_dir / CHECKPOINT, state, step, cfg, rig, pattern)
                if step >= total_steps or out_of_time:
                    total_steps = step
                    break
    bar.close()
    if progress and losses and max(losses) == 0.0:  # every pixel weighted 0: no visible pattern
        print(nothing_learnt(len(losses), data.name), file=sys.stderr, flush=True)
    leave_process_group(ranks)
    result = {"step": step, "losses": losses, "seconds": time.perf_counter() - start, "validation": rates}
    if progress:
        print(summary(result, total_steps, t.batch_size, ranks.world, out_dir))
    return result


@contextlib.contextmanager
def tensorboard_log(out_dir: Path, step: int, main: bool):
    """Rank 0's TensorBoard writer in OUT/tb (None on the other ranks), continuing after `step` (the
    step a resumed checkpoint saved), closed when the block ends, a failed one too: its thread then
    writes no more into a tb/ that `dotsim train` removes (dotsim.output_folder.removed_if_failed)."""
    from torch.utils.tensorboard import SummaryWriter

    writer = SummaryWriter(str(make_folder(out_dir) / "tb"), purge_step=step + 1) if main else None
    try:
        yield writer
    finally:
        if writer is not None:
            writer.close()


def nothing_learnt(steps: int, data_name: str) -> str:
    """The warning of a run whose loss was 0 at every step (every pixel weighted 0: nothing visible)."""
    return (f"warning: the loss was 0 at every one of {steps} step(s): the training frames show no visible "
            f"pixel (visibility = 1 nowhere), so nothing was learnt; `dotsim stats {data_name}` shows the "
            "visible share")


def stored_pattern(data: FrameSource, say: bool) -> np.ndarray | None:
    """The training data's pattern, for the checkpoint (inference matches a stride-2 network's depth
    edges against it); None where the source has none here (shards behind URLs, a dataset without its
    pattern file), with a warning when `say`."""
    try:
        return data.pattern
    except SourceError as error:
        if say:
            print(f"warning: no pattern to keep in the checkpoint ({error}); inference will give depth "
                  "edges the farther sample", file=sys.stderr)
        return None


def held_out_validation(validation: FrameSource | None, count: int, data: FrameSource) -> Validation | None:
    """Validation of `count` frames spread over `validation` (None without it), checked to share the
    training data's rig and to hold none of its frames."""
    if validation is None:
        return None
    check_rig(data.rig, validation.rig, "training data", validation.name)
    return Validation(validation.held_out(count, data, "training"), data.rig, validation.pattern)


def plan_steps(cfg: Config, data: FrameSource) -> tuple[int, int]:
    """(steps per epoch, the run's total steps); DataError when the data holds less than one batch."""
    t = cfg.train
    steps_per_epoch = len(data.frames) // t.batch_size
    if steps_per_epoch == 0:
        raise DataError(f"{data.name}: {len(data.frames)} frame(s) in split {data.split!r}, fewer than "
                        f"batch_size {t.batch_size}")
    total_steps = t.epochs * steps_per_epoch
    return steps_per_epoch, min(total_steps, t.max_steps) if t.max_steps > 0 else total_steps


def join_ranks(cfg: Config, rig: Rig, device: str, progress: bool) -> Ranks:
    """This process's rank of the run (trainer.distributed), checked: a CUDA device where asked for, a
    global batch that the ranks share evenly; a warning (rank 0) when the config's sizes do not fit
    the data's camera."""
    if device == "cuda" and not torch.cuda.is_available():
        raise DataError("--device cuda: no CUDA device is available; use --device cpu")
    ranks = join_process_group(device)
    if cfg.train.batch_size % ranks.world:
        raise DataError(f"[train].batch_size {cfg.train.batch_size} is the global batch and must divide "
                        f"evenly among the {ranks.world} processes")
    mismatch = resolution_mismatch(cfg, rig.camera.width, rig.camera.height)
    if mismatch and progress and ranks.main:
        print(f"warning: {mismatch}", flush=True)
    return ranks


def new_state(cfg: Config, rig: Rig, device: str, steps_per_epoch: int, total_steps: int) -> TrainingState:
    """A fresh network on `device` with its optimiser, schedule and loss scaler."""
    model = build_model(cfg, rig).to(device)
    opt, sched = make_optimizer(model, cfg, steps_per_epoch, total_steps)
    # float16's narrow range needs loss scaling; bfloat16 has float32's range and needs none.
    scaler = torch.amp.GradScaler(torch.device(device).type, enabled=cfg.train.amp == "float16")
    return TrainingState(model, opt, sched, scaler)


def optimiser_step(loss_of, state: TrainingState, batch: dict, cfg: Config, ranks: Ranks, step: int,
                   start: float, weights: tuple[float, float] | None = None
                   ) -> tuple[float, dict[str, float], float]:
    """One optimiser step on a batch with the loss weights of this step (loss_weights): (the global
    batch's loss, its parts, seconds since `start`), each the mean over the ranks, so all ranks stop
    together. FloatingPointError for a loss that is not finite."""
    with autocast(ranks.device, cfg.train.amp):
        loss, parts = loss_of(batch, weights)
    values = [float(loss.detach()), *parts.values(), time.perf_counter() - start]
    value, *part_values, elapsed = ranks.mean(torch.tensor(values, dtype=torch.float64)).tolist()
    if not math.isfinite(value):
        raise FloatingPointError(f"step {step}: loss is {value}; lower [train].lr")
    state.opt.zero_grad(set_to_none=True)
    state.scaler.scale(loss).backward()
    state.scaler.step(state.opt)
    state.scaler.update()
    state.sched.step()
    return value, dict(zip(parts, part_values, strict=True)), elapsed


def log_step(writer, step: int, at_end: bool, out_of_time: bool, cfg: Config, state: TrainingState,
             value: float, parts: dict[str, float], batch: dict, validate: Validation | None, device: str
             ) -> dict[str, float] | None:
    """TensorBoard after a step: the loss, its parts and the learning rate every [train].log_every steps,
    images every image_every, validation's rates and error image every val_every (returned), each at the
    run's end as well (validation also when the run stops for time)."""
    t = cfg.train
    if step % t.log_every == 0 or at_end:
        writer.add_scalar("loss/total", value, step)
        for k, v in parts.items():
            writer.add_scalar(f"loss/{k}", v, step)
        writer.add_scalar("lr", state.sched.get_last_lr()[0], step)
    if step % t.image_every == 0 or at_end:
        _log_images(writer, step, state.model, batch)
    if validate is None or not (step % t.val_every == 0 or at_end or out_of_time):
        return None
    rates, image = validate(state.model, device)
    for name, rate in rates.items():
        writer.add_scalar(f"validation/{name}", rate, step)
    writer.add_image("validation/ir_and_error_0_to_5_px", image, step, dataformats="HWC")
    return rates


def summary(result: dict, total_steps: int, batch_size: int, world: int, out_dir: Path) -> str:
    """The line a run ends with (and validation's rates under it)."""
    losses, seconds = result["losses"], result["seconds"]
    last = f"{losses[-1]:.4f}" if losses else "n/a (already complete)"
    line = (f"trained {len(losses)} step(s) to step {result['step']}/{total_steps} in {seconds:.1f} s "
            f"({len(losses) * batch_size / max(seconds, 1e-9):.1f} samples/s on {world} process(es)), last "
            f"loss {last}; checkpoint {out_dir / CHECKPOINT}; TensorBoard logs in {out_dir / 'tb'} "
            f"(tensorboard --logdir {out_dir / 'tb'})")
    rates = result["validation"]
    return line + ("\nvalidation: " + ", ".join(f"{k} {v:.4f}" for k, v in rates.items()) if rates else "")
