"""Training configuration: one TOML file with [model], [data] and [train] tables.

Every size of the network, the input pipeline and the optimisation is a value here, so the same code
builds a tiny CPU model for tests (configs/train_tiny.toml) and the published GigaDepth network
(configs/train_gigadepth.toml). Unknown keys and wrong types are errors naming the file and field.
"""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


class ConfigError(ValueError):
    """A training configuration value is missing, unknown or out of range."""


@dataclass(frozen=True)
class ModelConfig:
    """Network shape. Column = projector column normalised by the projector width, in [0, 1]."""

    backbone: str = "conv"  # "conv" (published plain stack) or "unet" (the seed's ablation)
    backbone_channels: tuple[int, ...] = (16, 24, 32, 40, 64, 64, 96, 160)
    backbone_kernels: tuple[int, ...] = (5, 3, 3, 3, 3, 5, 3, 3)
    unet_channels: tuple[int, ...] = (32, 64, 128)  # encoder widths below half resolution (unet only)
    lcn_window: int = 11
    lcn_eps: float = 1e-2
    classes: tuple[int, ...] = (16, 10, 8)  # classes per tree level; leaves = product
    overlaps: tuple[int, ...] = (0, 3, 4)  # extra children on each side of a parent's range
    # (offset, width) slice of the backbone channels feeding each classifier level and the regressor
    stage_inputs: tuple[tuple[int, int], ...] = ((0, 64), (32, 64), (64, 64), (96, 64))
    classifier_hidden: tuple[tuple[int, ...], ...] = ((64, 32), (32,), (32,))
    regressor_hidden: tuple[int, ...] = (32,)
    lines: int = 448  # distinct weight sets over the half-resolution rows (rows share when fewer)
    regress_neighbours: int = 1  # leaves on each side of the true one whose regressors are trained
    column_padding: float = 0.1  # target x' = (1 - 2 p) x + p keeps the column off the tree's ends
    chunk_pixels: int = 65536  # pixels per gathered-weight batch (bounds memory, not results)


@dataclass(frozen=True)
class DataConfig:
    """Input pipeline; sizes are in full-resolution camera pixels."""

    crop_width: int = 0  # 0 = full width
    crop_height: int = 0  # 0 = full height; crops start on even rows to keep half-res line identity
    vertical_jitter: int = 0  # image content shifted by up to this many rows against its line index
    noise_std: float = 0.0  # std of additive Gaussian noise, in the units of the frames' ir channel
    intensity_scale: tuple[float, float] = (1.0, 1.0)  # uniform random gain range
    workers: int = 0  # DataLoader worker processes


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation. The published setup is SGD with lr 4 and step decay, 10 epochs, batch 4."""

    epochs: int = 10
    max_steps: int = 0  # > 0 stops after this many optimiser steps (tests, benchmarks)
    batch_size: int = 4
    optimizer: str = "sgd"  # "sgd" or "adam"
    lr: float = 4.0
    momentum: float = 0.0
    weight_decay: float = 0.0
    lr_step_epochs: int = 3  # step decay: multiply lr by lr_gamma every lr_step_epochs epochs
    lr_gamma: float = 0.5
    ce_weights: tuple[float, ...] = (1.0, 1.0, 1.0)
    l1_weight: float = 1.0  # on the column in leaf units (column * leaves)
    edge_weight: float = 10.0  # pixel weight 1 + edge_weight * edge
    amp: bool = True  # mixed precision on CUDA (ignored on CPU)
    log_every: int = 10
    image_every: int = 100
    checkpoint_every: int = 200


@dataclass(frozen=True)
class Config:
    seed: int = 0
    model: ModelConfig = field(default_factory=ModelConfig)
    data: DataConfig = field(default_factory=DataConfig)
    train: TrainConfig = field(default_factory=TrainConfig)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def _tuples(value: Any) -> Any:
    """Lists from TOML/JSON become tuples so configs compare and hash like the dataclass defaults."""
    if isinstance(value, list | tuple):
        return tuple(_tuples(v) for v in value)
    return value


def _section(cls, table: dict[str, Any], where: str):
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(table) - set(fields))
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(fields)}")
    values = {}
    for name, value in table.items():
        default = getattr(cls(), name)
        value = _tuples(value)
        if isinstance(default, bool) != isinstance(value, bool) or (
            isinstance(default, int | float) and not isinstance(value, int | float)
        ) or (isinstance(default, str | tuple) and not isinstance(value, type(default))):
            raise ConfigError(f"{where}.{name}: {value!r} has the wrong type; expected like {default!r}")
        if isinstance(default, float):
            value = float(value)
        values[name] = value
    return cls(**values)


def config_from_dict(d: dict[str, Any], where: str = "config") -> Config:
    """Build and validate a Config from a TOML/JSON-shaped dict; `where` names the source in errors."""
    unknown = sorted(set(d) - {"seed", "model", "data", "train"})
    if unknown:
        raise ConfigError(f"{where}: unknown table(s) {unknown}; allowed: seed, [model], [data], [train]")
    cfg = Config(
        seed=int(d.get("seed", 0)),
        model=_section(ModelConfig, d.get("model", {}), f"{where} [model]"),
        data=_section(DataConfig, d.get("data", {}), f"{where} [data]"),
        train=_section(TrainConfig, d.get("train", {}), f"{where} [train]"),
    )
    validate(cfg, where)
    return cfg


def load_config(path: str | Path) -> Config:
    """Read a training TOML file; errors name the file and the offending field."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: training config file not found")
    try:
        d = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: not valid TOML: {e}") from e
    return config_from_dict(d, str(path))


def validate(cfg: Config, where: str = "config") -> None:
    m, t, dcfg = cfg.model, cfg.train, cfg.data
    levels = len(m.classes)
    if m.backbone not in ("conv", "unet"):
        raise ConfigError(f"{where} [model].backbone: {m.backbone!r}; allowed: 'conv', 'unet'")
    if len(m.backbone_channels) != len(m.backbone_kernels) or not m.backbone_channels:
        raise ConfigError(
            f"{where} [model]: backbone_channels and backbone_kernels need the same nonzero length"
        )
    if any(k % 2 == 0 for k in m.backbone_kernels):
        raise ConfigError(f"{where} [model].backbone_kernels: {m.backbone_kernels} must all be odd")
    if levels < 1 or any(c < 2 for c in m.classes):
        raise ConfigError(f"{where} [model].classes: {m.classes}; need at least one level of >= 2 classes")
    if len(m.overlaps) != levels or m.overlaps[0] != 0 or any(
        o < 0 or o >= c for o, c in zip(m.overlaps, m.classes, strict=True)
    ):
        raise ConfigError(
            f"{where} [model].overlaps: {m.overlaps}; need one per level, 0 for the first, 0 <= o < classes"
        )
    if len(m.classifier_hidden) != levels:
        raise ConfigError(f"{where} [model].classifier_hidden: need one list of widths per level ({levels})")
    if len(m.stage_inputs) != levels + 1:
        raise ConfigError(f"{where} [model].stage_inputs: need {levels + 1} (offset, width) pairs")
    out_ch = m.backbone_channels[-1]
    for off, width in m.stage_inputs:
        if off < 0 or width < 1 or off + width > out_ch:
            raise ConfigError(
                f"{where} [model].stage_inputs: slice ({off}, {width}) exceeds the {out_ch} backbone channels"
            )
    if m.lines < 1:
        raise ConfigError(f"{where} [model].lines: {m.lines} must be >= 1")
    if not 0 <= m.column_padding < 0.5:
        raise ConfigError(f"{where} [model].column_padding: {m.column_padding} must be in [0, 0.5)")
    if dcfg.crop_height % 2 or dcfg.crop_width % 2:
        raise ConfigError(f"{where} [data]: crop_width/crop_height must be even (half-resolution output)")
    if t.optimizer not in ("sgd", "adam"):
        raise ConfigError(f"{where} [train].optimizer: {t.optimizer!r}; allowed: 'sgd', 'adam'")
    if len(t.ce_weights) != levels:
        raise ConfigError(f"{where} [train].ce_weights: need one weight per level ({levels})")
    if t.batch_size < 1 or t.epochs < 1:
        raise ConfigError(f"{where} [train]: batch_size and epochs must be >= 1")
