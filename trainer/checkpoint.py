"""Checkpoints, written and read in one place, and predicting with a trained network: what training's
resume, `dotsim eval` and `dotsim infer` stand on.

RUN/checkpoint.pt holds everything a resume needs (model, optimiser, scheduler, loss scaler, step,
config, rig, RNG states: save_checkpoint, restore_checkpoint) and the training data's pattern for
inference (stored_reference), written atomically so a failed save leaves the last good one. The config
and rig it was trained with come along, so the network is rebuilt from the file alone (load_model). The
network's half-resolution column is turned into full-resolution disparity and depth here, once, for
evaluation and inference alike (predict_disparity).
"""

from __future__ import annotations

import random
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from dotsim.file_io import atomic_writer
from dotsim.rig.geometry import Rig, depth_to_disparity, disparity_to_depth, projector_column_to_depth
from trainer.config import Config, config_from_dict
from trainer.model import LOW_PRECISION, GigaDepthNet, autocast, build_model
from trainer.samples import DataError
from trainer.upsampling import full_resolution_disparity, pattern_reference, upsample_half

PRECISIONS = ("float32", *LOW_PRECISION)  # of inference (`--precision`)
CHECKPOINT = "checkpoint.pt"


@dataclass
class TrainingState:
    """What training changes step by step and a checkpoint keeps: the network, the optimiser, its
    learning-rate schedule and the loss scaler."""

    model: GigaDepthNet
    opt: torch.optim.Optimizer
    sched: object
    scaler: torch.amp.GradScaler


def save_checkpoint(path: Path, state: TrainingState, step: int, cfg: Config, rig: Rig,
                    pattern: np.ndarray | None) -> None:
    """Write the checkpoint of a run at `step` atomically (RNG states included, for an exact resume),
    with the training data's `pattern` (the projector image; None: none known), which inference
    matches a stride-2 network's output against on depth edges (stored_reference)."""
    atomic_torch_save({
        "model": state.model.state_dict(), "optimizer": state.opt.state_dict(),
        "scheduler": state.sched.state_dict(), "scaler": state.scaler.state_dict(), "step": step,
        "config": cfg.to_dict(), "rig": rig.to_dict(), "rng": _rng_states(),
        "pattern": None if pattern is None else np.asarray(pattern, np.float32),
        "torch_version": torch.__version__,
    }, path)


def restore_checkpoint(path: Path, resume: bool, state: TrainingState, cfg: Config, rig: Rig, source: str
                       ) -> int:
    """The step to start at: 0 without a checkpoint at `path`, else (with `resume`) the checkpoint's,
    its state loaded into `state` and the RNGs; DataError for a checkpoint without --resume, of another
    config (only [train].epochs and max_steps may change) or of another rig than `source`'s."""
    if not path.exists():
        return 0
    if not resume:
        raise DataError(f"{path}: exists; pass --resume to continue it or choose another --out")
    # read to CPU: load_state_dict moves each tensor to the model's device, and the RNG states
    # must stay CPU tensors (mapped to CUDA, torch.set_rng_state refuses them)
    ckpt, old_cfg, old_rig = load_checkpoint(path)
    if _without_length(old_cfg) != _without_length(cfg):
        raise DataError(f"{path}: was trained with another config; resume needs the same one "
                        "(only [train].epochs and max_steps may change)")
    check_rig(old_rig, rig, "checkpoint", source)
    state.model.load_state_dict(ckpt["model"])
    state.opt.load_state_dict(ckpt["optimizer"])
    state.sched.load_state_dict(ckpt["scheduler"])
    if ckpt["scaler"]:  # empty when saved disabled (CPU runs with the former amp = true)
        state.scaler.load_state_dict(ckpt["scaler"])
    _set_rng_states(ckpt["rng"])
    return ckpt["step"]


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


def _without_length(cfg: Config) -> Config:
    """The config without how long to train: a resumed run may be extended."""
    return replace(cfg, train=replace(cfg.train, epochs=1, max_steps=0))


def _rng_states() -> dict:
    return {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()}


def _set_rng_states(s: dict) -> None:
    torch.set_rng_state(s["torch"])
    np.random.set_state(s["numpy"])
    random.setstate(s["python"])




def load_checkpoint(path: str | Path, map_location="cpu") -> tuple[dict, Config, Rig]:
    """Read a checkpoint and the config and rig it was trained with; clear errors for other files."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: checkpoint not found")
    try:
        ckpt = torch.load(path, map_location=map_location, weights_only=False)
    except Exception as e:  # torch raises many kinds for non-checkpoint files
        raise DataError(f"{path}: not a readable torch checkpoint ({type(e).__name__}: {e})") from e
    if not isinstance(ckpt, dict) or not {"model", "config", "rig"} <= set(ckpt):
        raise DataError(f"{path}: not a dotsim trainer checkpoint (needs model, config and rig entries)")
    return ckpt, config_from_dict(ckpt["config"], f"{path} config"), Rig.from_dict(ckpt["rig"])


def check_rig(expected: Rig, found: Rig, what: str, source: str) -> None:
    """Refuse data whose rig (resolution, intrinsics, baseline) differs from the model's."""
    if expected != found:
        ours, theirs = found.to_dict(), expected.to_dict()
        diffs = [k for k in theirs if theirs[k] != ours[k]]
        # each differing value, both sides (a max_depth of 10 against 20 m, not the key alone)
        values = "; ".join(f"{k} {ours[k]} here, {theirs[k]} in the {what}" for k in diffs
                           if not isinstance(ours[k], dict))
        raise DataError(
            f"{source}: rig {found.name!r} ({found.camera.width}x{found.camera.height}) differs from the "
            f"{what}'s rig {expected.name!r} ({expected.camera.width}x{expected.camera.height}) in {diffs}"
            + (f" ({values})" if values else "") + "; allowed: data of the rig the network was trained on"
        )


def load_model(checkpoint: str | Path, device: str = "cpu") -> tuple[GigaDepthNet, Config, Rig]:
    """The trained network of a checkpoint on `device`, in eval mode, with its config and rig.

    The file is read to CPU whatever device wrote it (a CUDA run's checkpoint loads on a machine
    without one), then the network is moved to `device`."""
    ckpt, cfg, rig = load_checkpoint(checkpoint)
    model = build_model(cfg, rig)
    model.load_state_dict(ckpt["model"])
    return model.to(device).eval(), cfg, rig


def stored_reference(path: str | Path, rig: Rig) -> np.ndarray | None:
    """The pattern a checkpoint's network was trained on, as seen from infinity on the camera grid
    (trainer.upsampling.pattern_reference, as eval's SGBM sees it): what predict_disparity matches a
    stride-2 network's depth edges against. None for a checkpoint saved before checkpoints stored it
    or trained on data without a pattern here.
    The file is memory-mapped: its tables are not read again."""
    ckpt = torch.load(path, map_location="cpu", weights_only=False, mmap=True)
    pattern = ckpt.get("pattern")
    return None if pattern is None else pattern_reference(pattern, rig)


def predict_disparity(model: GigaDepthNet, rig: Rig, ir: np.ndarray, device: str = "cpu",
                      precision: str = "float32", reference: np.ndarray | None = None):
    """(disparity camera px, depth metres), each (H, W) float32, nan where the column gives no depth.

    precision: float32, or float16 / bfloat16 autocast (the column itself is computed in float32).
    reference: the pattern as seen from infinity on the camera grid (stored_reference, or the data's);
    a stride-2 network's pixels on depth edges then take the surface the pattern matches
    (trainer.upsampling.full_resolution_disparity), else the farther one."""
    model.eval()
    with torch.no_grad(), autocast(device, precision):
        x = torch.from_numpy(np.ascontiguousarray(ir, np.float32))[None, None].to(device)
        column = model(x)[0].float().cpu().numpy()
    height, width = rig.camera.height, rig.camera.width
    # Linear upsampling of the column keeps the samples at (2i, 2j) exact, so converting at full size
    # and reading those pixels back gives each sample's disparity at its own pixel.
    half = model.cfg.stride == 2
    full_column = upsample_half(column, height, width) if half else column
    disparity = depth_to_disparity(projector_column_to_depth(full_column, rig, normalised=True), rig)
    if half:
        disparity = full_resolution_disparity(disparity[0::2, 0::2], height, width, ir, reference)
    return disparity.astype(np.float32), disparity_to_depth(disparity, rig).astype(np.float32)


