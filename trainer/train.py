"""The training loop: teacher-forced tree losses, checkpoints with exact resume, TensorBoard logging.

RUN/checkpoint.pt holds everything a resume needs (model, optimiser, scheduler, step, config, rig, RNG
states); RUN/tb/ the TensorBoard scalars and images. Given the same config, data and seed a CPU run is
deterministic, and a resumed run continues with the losses an unbroken run would have had.
"""

from __future__ import annotations

import contextlib
import math
import random
import sys
import threading
import time
from dataclasses import replace
from functools import partial
from pathlib import Path

import numpy as np
import torch
from torch.nn.parallel import DistributedDataParallel
from tqdm import tqdm

from dotsim.false_colour import colourise
from dotsim.file_io import DiskFullError, atomic_writer, disk_full_error, is_disk_full, make_folder
from dotsim.rig import Rig, disparity_to_depth
from dotsim.solvable import solvable_pixels
from trainer.checkpoint import check_rig, load_checkpoint, predict_disparity
from trainer.config import Config, resolution_mismatch
from trainer.data import (
    DataError,
    FrameDataset,
    FrameRef,
    check_held_out,
    dataset_pattern,
    list_frames,
    make_loader,
    spread,
)
from trainer.distributed import ONE_PROCESS, Ranks, join_process_group, leave_process_group
from trainer.metrics import THRESHOLDS, outlier_counts, outlier_rate, valid_pixels
from trainer.model import GigaDepthNet, autocast, build_model

CHECKPOINT = "checkpoint.pt"


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def batch_loss(model: GigaDepthNet, batch: dict, cfg: Config, ranks: Ranks = ONE_PROCESS
               ) -> tuple[torch.Tensor, dict[str, float]]:
    """Weighted loss of one batch: sum_l ce_weights[l] * CE_l + l1_weight * L1, each the mean over the
    valid pixels weighted by 1 + edge_weight * edge (GigaDepth weights edges up: the column jumps there).

    With several ranks each holds part of the global batch; the means are over the global batch's pixel
    weight (times the number of ranks, as DDP averages the ranks' gradients), so the ranks' mean loss and
    gradient are the single-process ones."""
    feat = model.features(batch["ir"])
    valid = batch["valid"] & model.in_range(batch["row0"], batch["x0"], batch["column"])
    terms = model.loss_terms(feat, batch["row0"], batch["column"], valid, batch["x0"])
    weight = 1.0 + cfg.train.edge_weight * batch["edge"][valid]
    norm = ranks.mean(weight.sum()).clamp_min(1.0 / ranks.world)
    parts = {f"ce{k + 1}": (ce * weight).sum() / norm for k, ce in enumerate(terms["ce"])}
    parts["l1"] = (terms["l1"] * weight).sum() / norm
    loss = sum(w * parts[f"ce{k + 1}"] for k, w in enumerate(cfg.train.ce_weights))
    loss = loss + cfg.train.l1_weight * parts["l1"]
    return loss, {k: float(v.detach()) for k, v in parts.items()}


class TrainingLoss(torch.nn.Module):
    """batch_loss as a module: DDP synchronises the gradients of what runs through its module's forward."""

    def __init__(self, model: GigaDepthNet, cfg: Config, ranks: Ranks):
        super().__init__()
        self.model, self.cfg, self.ranks = model, cfg, ranks

    def forward(self, batch: dict) -> tuple[torch.Tensor, dict[str, float]]:
        return batch_loss(self.model, batch, self.cfg, self.ranks)


def lr_factor(cfg: Config, step: int, total_steps: int) -> float:
    """The factor on [train].lr at `step` of a run of `total_steps` (cosine and piecewise schedules; step
    decay is torch's StepLR)."""
    t = cfg.train
    done = min(step, total_steps) / max(total_steps, 1)
    if t.lr_schedule == "cosine":
        return t.lr_final + (1 - t.lr_final) * 0.5 * (1 + math.cos(math.pi * done))
    return t.lr_factors[min(int(done * len(t.lr_factors)), len(t.lr_factors) - 1)]


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


class _WriteErrors:
    """The file object torch.save writes through: keeps the OSError a write raised, which torch's
    writer reports only as RuntimeError("unexpected pos ...")."""

    def __init__(self, stream):
        self.stream, self.error = stream, None

    def write(self, data) -> int:
        try:
            return self.stream.write(data)
        except OSError as error:
            self.error = error
            raise

    def flush(self) -> None:
        self.stream.flush()


def atomic_torch_save(obj, path: Path) -> None:
    """torch.save to `path` atomically: a save that fails (a full disk: DiskFullError naming the
    file) leaves the previous file as it was."""
    with atomic_writer(path) as stream:
        writes = _WriteErrors(stream)
        try:
            torch.save(obj, writes)
        except RuntimeError:
            if writes.error is not None:
                raise writes.error from None  # atomic_writer turns ENOSPC into its one-line DiskFullError
            raise


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


def _without_length(cfg: Config) -> Config:
    """The config without how long to train: a resumed run may be extended."""
    return replace(cfg, train=replace(cfg.train, epochs=1, max_steps=0))


def _rng_states() -> dict:
    return {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()}


def _set_rng_states(s: dict) -> None:
    torch.set_rng_state(s["torch"])
    np.random.set_state(s["numpy"])
    random.setstate(s["python"])


class Validation:
    """A few held-out frames that training scores every [train].val_every steps: the network's o(t)
    over their valid pixels and over the solvable ones (dotsim/solvable.py, where the frames record
    their sensor), and the first frame's IR and |error| as an image. Read once, at the start."""

    def __init__(self, frames: list[FrameRef], rig: Rig, pattern: np.ndarray):
        self.rig, self.frames = rig, []
        for ref in frames:
            f = ref.read(("ir", "visibility", "disparity"))
            classes = {"all": valid_pixels(f["visibility"], f["disparity"])}
            depth = disparity_to_depth(f["disparity"], rig)
            if (solved := solvable_pixels(f["ir"], depth, rig, pattern, ref.scene_meta())) is not None:
                classes["solvable"] = classes["all"] & solved
            self.frames.append((f["ir"], f["disparity"].astype(np.float64), classes))

    def __call__(self, model: GigaDepthNet, device: str) -> tuple[dict[str, float], np.ndarray]:
        """({"all o(0.5)": rate, ...}, an RGB uint8 image of the first frame: its IR above its |error|,
        0..5 px on the turbo map, black where there is no ground truth or no estimate)."""
        counts: dict[str, np.ndarray] = {}
        for n, (ir, gt, classes) in enumerate(self.frames):
            pred = predict_disparity(model, self.rig, ir, device)[0]
            for name, selected in classes.items():
                pixels, over = outlier_counts(pred, gt, selected)
                counts[name] = counts.get(name, 0) + np.array([pixels, *over])
            if n == 0:
                grey = np.clip(ir / max(float(np.percentile(ir, 99.5)), 1e-12) * 255, 0, 255).astype(np.uint8)
                error = colourise(np.where(classes["all"], np.abs(pred - gt), np.nan), 0.0, 5.0)
                image = np.concatenate([np.repeat(grey[..., None], 3, 2), error[..., ::-1]], axis=0)
        model.train()
        rates = {f"{name} o({t:g})": outlier_rate(int(c[1 + k]), int(c[0]))
                 for name, c in counts.items() for k, t in enumerate(THRESHOLDS)}
        return rates, image


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


def train(cfg: Config, data_dir: str | Path, out_dir: str | Path, resume: bool = False,
          device: str = "cpu", split: str = "train", progress: bool = True, max_seconds: float = 0.0,
          val_data: str | Path | None = None, val_split: str = "all", val_frames: int = 4,
          progress_bar: bool = True) -> dict:
    """Train on `split` of data_dir into out_dir; returns {"step", "losses" (per step), "seconds",
    "validation" (the last validation's rates, {} without val_data)}.

    Launched as several processes (torchrun, or trainer.distributed.run_on_ranks), each is one DDP rank
    of the same run: each takes its share of every global batch, and rank 0 alone writes and prints.
    max_seconds > 0 stops (with a checkpoint) after the first step that ends past that wall time.
    val_data: `val_frames` frames spread over its `val_split` (held out from the training frames) are
    scored every [train].val_every steps and at the end (Validation), into TensorBoard.
    progress: print warnings and the summary, with a progress bar (progress_bar=False: without)."""
    from torch.utils.tensorboard import SummaryWriter

    out_dir = Path(out_dir)
    ckpt_path = out_dir / CHECKPOINT
    frames, rig, _ = list_frames(data_dir, split)
    t = cfg.train
    steps_per_epoch = len(frames) // t.batch_size
    if steps_per_epoch == 0:
        raise DataError(f"{data_dir}: {len(frames)} frame(s) in split {split!r}, fewer than batch_size "
                        f"{t.batch_size}")
    total_steps = t.epochs * steps_per_epoch
    if t.max_steps > 0:
        total_steps = min(total_steps, t.max_steps)
    if device == "cuda" and not torch.cuda.is_available():
        raise DataError("--device cuda: no CUDA device is available; use --device cpu")

    ranks = join_process_group(device)
    device = ranks.device
    if t.batch_size % ranks.world:
        raise DataError(f"[train].batch_size {t.batch_size} is the global batch and must divide evenly "
                        f"among the {ranks.world} processes")
    mismatch = resolution_mismatch(cfg, rig.camera.width, rig.camera.height)
    if mismatch and progress and ranks.main:
        print(f"warning: {mismatch}", flush=True)
    validation = None
    if val_data is not None and ranks.main:
        held_out, val_rig, _ = list_frames(val_data, val_split)
        check_rig(rig, val_rig, "training data", str(val_data))
        held_out = spread(held_out, val_frames)
        check_held_out(held_out, frames, f"{val_data}: validation frames (split {val_split!r})",
                       f"the training frames of {data_dir} (split {split!r})")
        validation = Validation(held_out, rig, dataset_pattern(val_data, rig))
    seed_everything(cfg.seed)
    model = build_model(cfg, rig).to(device)
    opt, sched = make_optimizer(model, cfg, steps_per_epoch, total_steps)
    # float16's narrow range needs loss scaling; bfloat16 has float32's range and needs none.
    scaler = torch.amp.GradScaler(torch.device(device).type, enabled=t.amp == "float16")
    step = 0
    if ckpt_path.exists():
        if not resume:
            raise DataError(f"{ckpt_path}: exists; pass --resume to continue it or choose another --out")
        # read to CPU: load_state_dict moves each tensor to the model's device, and the RNG states
        # must stay CPU tensors (mapped to CUDA, torch.set_rng_state refuses them)
        ckpt, old_cfg, old_rig = load_checkpoint(ckpt_path)
        if _without_length(old_cfg) != _without_length(cfg):
            raise DataError(f"{ckpt_path}: was trained with another config; resume needs the same one "
                            "(only [train].epochs and max_steps may change)")
        check_rig(old_rig, rig, "checkpoint", str(data_dir))
        model.load_state_dict(ckpt["model"])
        opt.load_state_dict(ckpt["optimizer"])
        sched.load_state_dict(ckpt["scheduler"])
        if ckpt["scaler"]:  # empty when saved disabled (CPU runs with the former amp = true)
            scaler.load_state_dict(ckpt["scaler"])
        step = ckpt["step"]
        _set_rng_states(ckpt["rng"])
    loss_of = TrainingLoss(model, cfg, ranks)
    if ranks.world > 1:  # BatchNorm statistics are global already (GlobalBatchNorm2d): no buffers to send
        loss_of = DistributedDataParallel(loss_of, forward_sync_buffers=False)
    if ranks.main:
        make_folder(out_dir)
        writer = SummaryWriter(str(out_dir / "tb"), purge_step=step + 1)  # step itself was logged and saved

    def save() -> None:
        atomic_torch_save({
            "model": model.state_dict(), "optimizer": opt.state_dict(), "scheduler": sched.state_dict(),
            "scaler": scaler.state_dict(), "step": step, "config": cfg.to_dict(), "rig": rig.to_dict(),
            "rng": _rng_states(), "torch_version": torch.__version__,
        }, ckpt_path)

    ds = FrameDataset(frames, rig, cfg.data, cfg.seed, augment=True, stride=cfg.model.stride)
    losses: list[float] = []
    rates: dict[str, float] = {}
    start = time.perf_counter()
    model.train()
    progress = progress and ranks.main
    bar = tqdm(total=total_steps, initial=step, desc="train", unit="step",
               disable=not (progress and progress_bar))
    try:
        while step < total_steps:
            epoch, within = divmod(step, steps_per_epoch)
            loader = make_loader(ds, t.batch_size, epoch, within * t.batch_size, cfg.data.workers, ranks.rank,
                                 ranks.world)
            for batch in loader:
                batch = {k: v.to(device) for k, v in batch.items()}
                with autocast(device, t.amp):
                    loss, parts = loss_of(batch)
                # means over the ranks: the global batch's loss, and one elapsed time so all ranks stop
                # together
                values = [float(loss.detach()), *parts.values(), time.perf_counter() - start]
                value, *part_values, elapsed = ranks.mean(torch.tensor(values, dtype=torch.float64)).tolist()
                parts = dict(zip(parts, part_values, strict=True))
                if not math.isfinite(value):
                    raise FloatingPointError(f"step {step}: loss is {value}; lower [train].lr")
                opt.zero_grad(set_to_none=True)
                scaler.scale(loss).backward()
                scaler.step(opt)
                scaler.update()
                sched.step()
                step += 1
                losses.append(value)
                bar.update(1)
                bar.set_postfix(loss=f"{value:.4f}", epoch=epoch)
                out_of_time = 0 < max_seconds < elapsed
                if ranks.main:  # rank 0 alone writes
                    if step % t.log_every == 0 or step == total_steps:
                        writer.add_scalar("loss/total", value, step)
                        for k, v in parts.items():
                            writer.add_scalar(f"loss/{k}", v, step)
                        writer.add_scalar("lr", sched.get_last_lr()[0], step)
                    if step % t.image_every == 0 or step == total_steps:
                        _log_images(writer, step, model, batch)
                    if validation is not None and (step % t.val_every == 0 or step == total_steps
                                                   or out_of_time):
                        rates, image = validation(model, device)
                        for name, rate in rates.items():
                            writer.add_scalar(f"validation/{name}", rate, step)
                        writer.add_image("validation/ir_and_error_0_to_5_px", image, step, dataformats="HWC")
                    if step % t.checkpoint_every == 0 or step == total_steps or out_of_time:
                        save()
                if step >= total_steps or out_of_time:
                    total_steps = step
                    break
    except BaseException:
        if ranks.main:
            writer.close()  # its thread flushes no more into a tb/ the caller may remove
        raise
    bar.close()
    if progress and losses and max(losses) == 0.0:  # every pixel weighted 0: no visible pattern
        print(f"warning: the loss was 0 at every one of {len(losses)} step(s): the training frames show no "
              f"visible pixel (visibility = 1 nowhere), so nothing was learnt; `dotsim stats {data_dir}` "
              "shows the visible share", file=sys.stderr, flush=True)
    if ranks.main:
        writer.close()
    leave_process_group(ranks)
    seconds = time.perf_counter() - start
    if progress:
        last = f"{losses[-1]:.4f}" if losses else "n/a (already complete)"
        print(f"trained {len(losses)} step(s) to step {step}/{total_steps} in {seconds:.1f} s "
              f"({len(losses) * t.batch_size / max(seconds, 1e-9):.1f} samples/s on {ranks.world} "
              f"process(es)), last loss {last}; checkpoint {ckpt_path}; TensorBoard logs in "
              f"{out_dir / 'tb'} (tensorboard --logdir {out_dir / 'tb'})")
    if progress and rates:
        print("validation: " + ", ".join(f"{k} {v:.4f}" for k, v in rates.items()))
    return {"step": step, "losses": losses, "seconds": seconds, "validation": rates}
