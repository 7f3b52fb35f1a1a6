"""Training configuration: one TOML file with a top-level seed and [model], [data] and [train] tables.

Every size of the network, the input pipeline and the optimisation is a value here, so the same code
builds a tiny CPU model for tests (dotsim/configs/train_tiny.toml) and the published GigaDepth network
(dotsim/configs/train_gigadepth.toml). Each key is one `setting(...)` line (dotsim.config_schema): default,
meaning and allowed values, from which come the validation, its errors (file, key, value, what is
allowed, "did you mean") and docs/TRAIN_CONFIG.md. Rules spanning keys are in `validate`.
Column = projector column normalised by the projector width, in [0, 1]; sizes in full-resolution
camera pixels unless said.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dotsim import config_schema
from dotsim.config_schema import Checked, ConfigError, FloatRange, setting
from dotsim.configs import config_path


@dataclass(frozen=True)
class ModelConfig(Checked):
    backbone: str = setting("conv", "network body: conv (the published plain stack) or unet (the UNet "
                            "ablation of GigaDepth's original code)", choices=("conv", "unet"))
    backbone_channels: tuple[int, ...] = setting((16, 24, 32, 40, 64, 64, 96, 160), "output channels of "
                                                 "each backbone conv", low=1, min_items=1)
    backbone_kernels: tuple[int, ...] = setting((5, 3, 3, 3, 3, 5, 3, 3), "kernel size of each backbone "
                                                "conv (odd; only the first conv is strided)", low=1,
                                                min_items=1)
    stride: int = setting(2, "stride of the first backbone conv: 2 (published) works at half resolution, "
                          "1 at full resolution (GigaDepth's supplementary, for sparser patterns): output "
                          "pixel (i, j) sits on full-resolution pixel (stride i, stride j)", choices=(1, 2))
    unet_channels: tuple[int, ...] = setting((32, 64, 128), "encoder widths below half resolution (unet "
                                             "only)", low=1)
    lcn_window: int = setting(11, "LCN window side, px (odd)", low=1)
    lcn_eps: float = setting(1e-2, "eps of LCN (I - mean) / (std + eps), in the ir channel's units",
                             low=0.0, low_open=True)
    classes: tuple[int, ...] = setting((16, 10, 8), "classes per tree level; leaves = their product",
                                       low=2, min_items=1)
    overlaps: tuple[int, ...] = setting((0, 3, 4), "extra children scored on each side of a parent's "
                                        "range, per level (0 for the first, below that level's classes)",
                                        low=0)
    stage_inputs: tuple[tuple[int, int], ...] = setting(((0, 64), (32, 64), (64, 64), (96, 64)),
                                                        "(offset, width) slice of the backbone's output "
                                                        "channels feeding each classifier level and the "
                                                        "regressor", low=0)
    classifier_hidden: tuple[tuple[int, ...], ...] = setting(((64, 32), (32,), (32,)), "hidden widths of "
                                                             "each level's classifier MLP", low=1)
    regressor_hidden: tuple[int, ...] = setting((32,), "hidden widths of the leaf regressor MLP", low=1)
    lines: int = setting(448, "distinct weight sets over the half-resolution rows (rows share when fewer)",
                         low=1)
    regress_neighbours: int = setting(1, "leaves on each side of the true one whose regressors are trained",
                                      low=0)
    min_depth: float = setting(0.0, "nearest depth the network is asked to find, m: > 0 restricts every "
                               "level of the tree to the classes whose projector columns a pixel's image "
                               "column allows for depths from it to the rig's max_depth (as SGBM's disparity "
                               "range), in training and inference; 0 = every class (GigaDepth's)", low=0.0)
    column_padding: float = setting(0.1, "p of the target x' = (1 - 2 p) x + p, which keeps the column off "
                                    "the tree's ends", low=0.0, high=0.5, high_open=True)
    chunk_pixels: int = setting(65536, "pixels per gathered-weight batch (bounds memory, not results)",
                                low=1)


@dataclass(frozen=True)
class DataConfig(Checked):
    crop_width: int = setting(0, "training crop width (even; 0 = full width: with crop_height 0, batches of "
                              "full frames, as GigaDepth trains)", low=0)
    crop_height: int = setting(0, "training crop height (even; 0 = full height); crops start on even rows "
                               "to keep half-resolution line identity", low=0)
    near_share: float = setting(0.0, "share of the crops centred on a random valid pixel nearer than "
                                "near_depth, where the frame has one (near surfaces are rare in few-object "
                                "scenes); 0: every crop origin uniform", low=0.0, high=1.0)
    near_depth: float = setting(2.0, "m: the depth below which near_share's crops look for pixels",
                                low=0.0, low_open=True)
    vertical_jitter: int = setting(0, "image content shifted by up to this many rows against its line "
                                   "index", low=0)
    noise_std: float = setting(0.0, "std of additive Gaussian noise, in the units of the frames' ir "
                               "channel", low=0.0)
    intensity_scale: FloatRange = setting((1.0, 1.0), "uniform random gain range", low=0.0)
    slant: float = setting(0.0, "degrees: each crop resampled as the pattern would look on a plane at its "
                           "median disparity tilted by angles drawn in [-slant, slant] about the vertical "
                           "axis (the rows stretched) and the horizontal one (each row shifted against the "
                           "next); the nearer the crop, the larger the change, as on real surfaces; 0: none",
                           low=0.0, high=80.0)
    slant_depth: float = setting(0.0, "m: only crops whose median GT depth is nearer than this are tilted by "
                                 "slant; 0: every crop", low=0.0)
    uniform_noise: float = setting(0.0, "GigaDepth's noise: each sample adds noise uniform in [0, a) per "
                                   "pixel, a = U(0, 1) x this, in the ir channel's units (full scale 1; "
                                   "GigaDepth: 0.3); 0: none", low=0.0)
    edge_threshold: float = setting(0.0, "> 0: the loss's edge mask is GigaDepth's, Sobel(disparity) "
                                    "above this (cv2's 3 x 3 kernel: a step of D px gives 4 D; GigaDepth: "
                                    "10) dilated by an ellipse of edge_radius px, instead of the edge mask "
                                    "the frames store", low=0.0)
    edge_radius: int = setting(10, "px: the ellipse edge_threshold's mask is dilated by (GigaDepth: 10)",
                               low=0)
    workers: int = setting(0, "DataLoader worker processes (0 = load in the training process)", low=0)
    cache_mb: int = setting(0, "decoded frames kept in memory, up to this many MB (0 = read every time); "
                            "needs workers = 0", low=0)


AMP_CHOICES = ("off", "float16", "bfloat16")


@dataclass(frozen=True)
class TrainConfig(Checked):
    # The published setup is SGD with lr 4 and step decay, 10 epochs, batch 4.
    epochs: int = setting(10, "passes over the training frames", low=1)
    max_steps: int = setting(0, "> 0 stops after this many optimiser steps (tests, benchmarks)", low=0)
    batch_size: int = setting(4, "frames per optimiser step", low=1)
    optimizer: str = setting("sgd", "optimiser", choices=("sgd", "adam"))
    lr: float = setting(4.0, "learning rate", low=0.0, low_open=True)
    momentum: float = setting(0.0, "SGD momentum", low=0.0, high=1.0)
    weight_decay: float = setting(0.0, "L2 weight decay", low=0.0)
    lr_schedule: str = setting("step", "how the learning rate changes over the run: step (times lr_gamma "
                               "every lr_step_epochs epochs), cosine (from lr down to lr x lr_final at the "
                               "run's last step) or piecewise (lr x each of lr_factors in turn, for equal "
                               "shares of the run's steps: GigaDepth's code)",
                               choices=("step", "cosine", "piecewise"))
    lr_step_epochs: int = setting(3, "step decay: multiply lr by lr_gamma every lr_step_epochs epochs",
                                  low=1)
    lr_gamma: float = setting(0.5, "step decay factor", low=0.0, high=1.0, low_open=True)
    lr_final: float = setting(0.01, "cosine: the factor on lr at the run's last step", low=0.0, high=1.0)
    lr_factors: tuple[float, ...] = setting((1.0, 0.5, 0.25, 0.12, 0.01), "piecewise: the factors on lr, "
                                            "each for an equal share of the run's steps (over 10 "
                                            "epochs these change at epochs 2, 4, 6, 8; GigaDepth's code, "
                                            "one epoch early: [1, .5, .5, .25, .25, .12, .12, .01, .01, "
                                            ".01])", low=0.0, min_items=1)
    ce_weights: tuple[float, ...] = setting((1.0, 1.0, 1.0), "weight of each tree level's cross-entropy",
                                            low=0.0)
    l1_weight: float = setting(1.0, "weight of the L1 on the column in leaf units (column * leaves)",
                               low=0.0)
    l1_weight_end: float = setting(0.0, "> 0: the L1 weight ramps linearly from l1_weight at the first step "
                                   "to this at the run's last (GigaDepth: 500 -> 2000 on the normalised "
                                   "column, i.e. divided by (1 - 2 column_padding) x leaves here); 0: "
                                   "l1_weight throughout", low=0.0)
    edge_weight: float = setting(10.0, "pixel weight 1 + edge_weight * edge", low=0.0)
    edge_weights: tuple[float, ...] = setting((), "a ramp of edge_weight: each value for an equal share of "
                                              "the run's steps (GigaDepth: [0, 1, 2, 2, 5]); empty: "
                                              "edge_weight throughout", low=0.0)
    amp: str = setting("off", "mixed precision on any device: off (float32), float16 (with a gradient "
                       "scaler) or bfloat16 (no scaler needed); older configs' true / false read as float16 "
                       "/ off",
                       choices=AMP_CHOICES)
    log_every: int = setting(10, "steps between logged losses", low=1)
    image_every: int = setting(100, "steps between logged images", low=1)
    checkpoint_every: int = setting(200, "steps between checkpoints (and one at the end)", low=1)
    val_every: int = setting(500, "steps between scorings of the validation frames (`dotsim train "
                             "--val-data`; and one at the end)", low=1)


@dataclass(frozen=True)
class Config(Checked):
    """A validated training configuration."""
    seed: int = setting(0, "seed of the initial weights, the frame order and the augmentations", low=0,
                        high=2**32 - 1)
    model: ModelConfig = field(default_factory=ModelConfig)
    data: DataConfig = field(default_factory=DataConfig)
    train: TrainConfig = field(default_factory=TrainConfig)

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe nested dict of every value (lists for tuples), as stored in checkpoints."""
        return config_schema.to_dict(self)


def config_from_dict(d: dict[str, Any], source: str = "<dict>") -> Config:
    """Build and validate a Config from a TOML/JSON-shaped dict; `source` names it in errors."""
    train = d.get("train")
    if isinstance(train, dict) and isinstance(train.get("amp"), bool):
        # [train].amp was a boolean (float16 on CUDA) before it named a precision: checkpoints and
        # configs written then still load.
        d = {**d, "train": {**train, "amp": "float16" if train["amp"] else "off"}}
    cfg = config_schema.from_dict(Config, d, source)
    validate(cfg, source)
    return cfg


def load_config(path: str | Path) -> Config:
    """Read a training TOML file, or a built-in config by name (dotsim.configs); errors name the file,
    the key, the value and what is allowed."""
    path = config_path(path)
    return config_from_dict(config_schema.read_toml(path), str(path))


def validate(cfg: Config, source: str = "<dict>") -> None:
    """Rules spanning several keys; raises ConfigError naming `source`, the key and the value."""
    m, t, dcfg = cfg.model, cfg.train, cfg.data
    levels = len(m.classes)

    def fail(key: str, value: Any, problem: str, allowed: str) -> ConfigError:
        return config_schema.value_error(f"{source}: {key}", value, problem, allowed)

    if len(m.backbone_kernels) != len(m.backbone_channels):
        raise fail("[model] backbone_kernels", m.backbone_kernels, "not one per backbone channel entry",
                   f"{len(m.backbone_channels)} odd kernel sizes")
    if any(k % 2 == 0 for k in m.backbone_kernels):
        raise fail("[model] backbone_kernels", m.backbone_kernels, "an even kernel size", "odd sizes")
    if m.lcn_window % 2 == 0:
        raise fail("[model] lcn_window", m.lcn_window, "even", "an odd window")
    if len(m.overlaps) != levels or m.overlaps[0] != 0 or any(
        o >= c for o, c in zip(m.overlaps, m.classes, strict=True)
    ):
        raise fail("[model] overlaps", m.overlaps, "does not fit classes = "
                   f"{config_schema.toml_text(m.classes)}",
                   f"{levels} integers, 0 for the first level, 0 <= overlap < that level's classes")
    if len(m.classifier_hidden) != levels:
        raise fail("[model] classifier_hidden", m.classifier_hidden, "not one list per tree level",
                   f"{levels} lists of hidden widths")
    if len(m.stage_inputs) != levels + 1:
        raise fail("[model] stage_inputs", m.stage_inputs, "not one slice per level and the regressor",
                   f"{levels + 1} [offset, width] pairs")
    out_ch = m.backbone_channels[-1]
    for off, width in m.stage_inputs:
        if width < 1 or off + width > out_ch:
            raise fail("[model] stage_inputs", m.stage_inputs, f"slice [{off}, {width}] is empty or exceeds "
                       f"the {out_ch} backbone output channels", "offset + width <= the last "
                       "backbone_channels entry, width >= 1")
    for key in ("crop_width", "crop_height"):
        if getattr(dcfg, key) % 2:
            raise fail(f"[data] {key}", getattr(dcfg, key), "odd (the output is at half resolution)",
                       "an even number of pixels, or 0")
    if dcfg.cache_mb and dcfg.workers:
        # a loader worker lives one epoch and reads each frame once in it: its cache would never be hit
        raise fail("[data] cache_mb", dcfg.cache_mb, f"set with workers = {dcfg.workers}",
                   "0, or workers = 0 (the training process keeps the cache)")
    if len(t.ce_weights) != levels:
        raise fail("[train] ce_weights", t.ce_weights, "not one weight per tree level",
                   f"{levels} weights")


def output_rows(cfg: ModelConfig, camera_height: int) -> int:
    """Rows of the network's output for a camera of this height: ceil(height / stride)."""
    return -(-camera_height // cfg.stride)


def resolution_mismatch(cfg: Config, camera_width: int, camera_height: int) -> str | None:
    """Why `cfg` does not fit a camera of this size, or None. The per-line weight tables are made for
    a number of output rows: `lines` must divide them (each line then covers whole rows, as
    configured) and not exceed them (lines beyond the last row would never train)."""
    rows = output_rows(cfg.model, camera_height)
    lines = cfg.model.lines
    if lines <= rows and rows % lines == 0:
        return None
    kind = "half-resolution" if cfg.model.stride == 2 else "full-resolution"
    return (f"[model] lines = {lines} does not fit the data's {camera_width} x {camera_height} camera "
            f"({rows} {kind} rows, {rows / lines:.2f} rows per line): the config was sized for "
            f"another resolution; choose lines dividing {rows} (the built-in train_cpu: 608 x 448)")


def config_reference_markdown() -> str:
    """docs/TRAIN_CONFIG.md: every key with its type, allowed values, default and meaning."""
    return config_schema.reference_markdown(Config, "Training configuration reference", (
        "Generated from `trainer/config.py` (`python -m trainer.config > docs/TRAIN_CONFIG.md`); a test "
        "checks that this file is current. The generator's config is in docs/CONFIG.md; how the "
        "trainer uses these values is in docs/TRAINER.md.\n\n"
        "A training config is a TOML file with the keys below; every key is optional and takes its "
        "default when left out. An unknown key, a value of the wrong type or out of range, or values "
        "that do not fit together (one overlap, classifier and loss weight per tree level, stage slices "
        "inside the backbone's channels) stop `dotsim train` before anything is read or written, with a "
        "message naming the file, the key, the value and what is allowed. The resolved config is stored "
        "in every checkpoint."))


if __name__ == "__main__":
    print(config_reference_markdown())
