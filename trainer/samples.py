"""Training samples from dotsim shards: IR crops with the GT projector column at the network's output
resolution (half, or full with [model] stride 1).

A sample keeps the identity of the network's lines: crops start on full-resolution rows that are
multiples of the network's stride and carry their first output row (`row0`) and column (`x0`), so the
per-line weights see the rows they are meant for. The targets are read at the full-resolution pixels
the outputs sit on, (stride i, stride j) of the crop (trainer/model.py), so no target is interpolated.
Augmentations (gain, noise, vertical jitter) draw from an RNG keyed by (seed, epoch, frame index): the
same sample comes out in any worker and after a resume.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, Sampler

from dotsim.data import IndexedSample, index_shards, pattern_file, read_indexed, resolve, stage_shards
from dotsim.dataset import FormatError, open_dataset, read_frame, read_scene_meta
from dotsim.patterns import PatternError, load_pattern
from dotsim.rig import Rig
from trainer.config import DataConfig

TRAIN_CHANNELS = ("ir", "visibility", "edge", "projector_column")


class DataError(ValueError):
    """The data folder cannot be used with this configuration or checkpoint."""


@dataclass(frozen=True)
class FrameRef:
    """One frame: its EXR in a dataset folder, or its sample in a WebDataset shard (`sample`)."""

    path: Path
    scene_index: int
    frame_index: int
    sample: IndexedSample | None = None

    def read(self, channels) -> dict[str, np.ndarray]:
        if self.sample is None:
            return read_frame(self.path, channels=channels)
        frame = read_indexed(self.sample, channels)
        return {c: frame[c] for c in channels}

    def stored_channels(self) -> set[str]:
        """The channels the frame stores (an export's sample may hold fewer than its scene.json lists)."""
        if self.sample is None:
            return set(self.scene_meta().get("channels", ()))
        return {ext.split(".")[0] for ext, _, _ in self.sample.members}

    def scene_meta(self) -> dict:
        """The frame's scene.json dict."""
        if self.sample is None:
            return read_scene_meta(self.path.parent)
        return read_indexed(self.sample, channels=())["meta"]


def _no_split_error(data: str, split: str, splits: list) -> DataError:
    present: dict[str, int] = {}
    for s in splits:
        present[str(s)] = present.get(str(s), 0) + 1
    return DataError(f"{data}: no scenes with split {split!r} "
                     f"(splits present: {present or 'none, empty dataset'}); choose one of those or 'all'")


def list_frames(data: str | Path, split: str, cache_dir: str | Path | None = None
                ) -> tuple[list[FrameRef], Rig, dict]:
    """Frames of the scenes of `split` ("all" for every scene) and the one rig they share.

    data: a dataset folder, or WebDataset shards of `dotsim export` (its folder, shard paths, a brace
    pattern, URLs: dotsim.data.resolve); shards behind URLs are first copied to `cache_dir`
    (dotsim.data.stage_shards). Frames keep the dataset's order either way, so a seeded run sees the
    same samples from both forms. Returns (frames, rig, pattern meta of the first scene). Errors name
    the data, the split and the splits present, or the scene whose rig differs from the first one's.
    """
    try:
        source = resolve(data)
        if source.folder is None:
            return _list_shard_frames(str(data), stage_shards(source, cache_dir), split)
        ds = open_dataset(source.folder)
    except FormatError as e:
        raise DataError(f"{data}: not a usable dotsim dataset: {e}") from e
    scenes = ds.scenes if split == "all" else ds.split(split)
    if not scenes:
        raise _no_split_error(str(data), split, [s.split for s in ds.scenes])
    frames, rigs = [], _OneRig()
    for s in scenes:
        rigs.check(read_scene_meta(s.path), s.path)
        frames += [FrameRef(p, s.scene_index, k) for k, p in enumerate(s.frame_paths)]
    return frames, rigs.rig, rigs.pattern


def dataset_pattern(data, rig: Rig) -> np.ndarray:
    """The projector pattern the data was rendered with (its pattern.png, or an export's), checked
    against the rig's projector; DataError naming the file otherwise."""
    try:
        return load_pattern(pattern_file(data), (rig.projector.height, rig.projector.width)).image
    except PatternError as e:
        raise DataError(str(e)) from e


def spread(frames: list, count: int) -> list:
    """`count` items spread evenly over `frames` (all of them when there are fewer, or count is 0)."""
    if count <= 0 or len(frames) <= count:
        return list(frames)
    return [frames[k] for k in np.linspace(0, len(frames) - 1, count).round().astype(int)]


def check_held_out(frames: list[FrameRef], others: list[FrameRef], what: str, where: str) -> None:
    """DataError when any of `frames` (`what`) is one of `others` (`where`): validation frames must be
    held out from the frames they judge."""
    taken = {(f.path, f.scene_index, f.frame_index) for f in others}
    if any((f.path, f.scene_index, f.frame_index) in taken for f in frames):
        raise DataError(f"{what} overlap {where}; give another split or dataset")


class _OneRig:
    """The rig and pattern of the first scene seen; DataError for a scene with another rig."""

    rig = pattern = first = None

    def check(self, meta: dict, where) -> None:
        scene_rig = Rig.from_dict(meta["rig"])
        if self.rig is None:
            self.rig, self.pattern, self.first = scene_rig, meta["pattern"], where
        elif scene_rig != self.rig:
            raise DataError(f"{where}: its rig differs from {self.first}'s; a dataset for training has "
                            "one rig")


def _list_shard_frames(data: str, source, split: str) -> tuple[list[FrameRef], Rig, dict]:
    frames, rigs, splits = [], _OneRig(), {}
    for sample in index_shards(source):
        info = read_indexed(sample, channels=())
        if split != "all" and info["split"] != split:
            splits[info["scene_index"]] = info["split"]
            continue
        if info["scene_index"] not in splits:
            splits[info["scene_index"]] = info["split"]
            rigs.check(info["meta"], f"{sample.shard} ({sample.key})")
        frames.append(FrameRef(Path(sample.shard), info["scene_index"], info["frame_index"], sample))
    if not frames:
        raise _no_split_error(data, split, list(splits.values()))
    return frames, rigs.rig, rigs.pattern


def frame_targets(frame: dict[str, np.ndarray], rig: Rig) -> dict[str, np.ndarray]:
    """Full-resolution arrays of one frame: ir (float32), column (normalised by the projector width,
    nan where invalid), valid (pattern visible, column finite and inside the projector image), edge."""
    column = frame["projector_column"].astype(np.float32) / rig.projector.width
    valid = (frame["visibility"] > 0) & np.isfinite(column) & (column >= 0) & (column <= 1)
    return {
        "ir": frame["ir"].astype(np.float32),
        "column": np.where(valid, column, np.nan).astype(np.float32),
        "valid": valid,
        "edge": frame["edge"].astype(np.float32),
    }


class FrameDataset(Dataset):
    """Frames as training samples; `augment` turns on crops and GigaDepth's augmentations. `stride`:
    the network's ([model] stride), whose output pixels the targets are read at."""

    def __init__(self, frames: list[FrameRef], rig: Rig, cfg: DataConfig, seed: int, augment: bool,
                 stride: int = 2):
        self.frames, self.rig, self.cfg, self.seed, self.augment = frames, rig, cfg, seed, augment
        self.stride = stride
        self.epoch = 0
        h, w = rig.camera.height, rig.camera.width
        self.crop_h = min(cfg.crop_height or h, h - h % 2)
        self.crop_w = min(cfg.crop_width or w, w - w % 2)
        self._cached: dict[int, dict[str, np.ndarray]] = {}
        self._cache_left = cfg.cache_mb * 2**20

    def __len__(self) -> int:
        return len(self.frames)

    def targets(self, i: int) -> dict[str, np.ndarray]:
        """frame_targets of frame i, kept (read-only) while [data].cache_mb lasts: a crop uses 2 % of
        a 608 x 448 frame, yet reading and decoding the frame took 21 ms, a third of a CPU step."""
        if i in self._cached:
            return self._cached[i]
        t = frame_targets(self.frames[i].read(TRAIN_CHANNELS), self.rig)
        size = sum(a.nbytes for a in t.values())
        if size <= self._cache_left:
            for a in t.values():
                a.flags.writeable = False
            self._cached[i], self._cache_left = t, self._cache_left - size
        return t

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        t = self.targets(i)
        h, w = t["ir"].shape
        rng = np.random.default_rng([self.seed, self.epoch, i])
        y0 = x0 = jitter = 0
        if self.augment:
            y0 = self.stride * int(rng.integers(0, (h - self.crop_h) // self.stride + 1))
            x0 = int(rng.integers(0, w - self.crop_w + 1))
            j = self.cfg.vertical_jitter
            jitter = int(np.clip(rng.integers(-j, j + 1), -y0, h - self.crop_h - y0)) if j else 0
        rows = slice(y0 + jitter, y0 + jitter + self.crop_h)
        cols = slice(x0, x0 + self.crop_w)
        ir = np.array(t["ir"][rows, cols])  # a copy: the cached frame stays as read
        if self.augment:
            ir = ir * rng.uniform(*self.cfg.intensity_scale)
            if self.cfg.noise_std > 0:
                ir = ir + rng.normal(0.0, self.cfg.noise_std, ir.shape).astype(np.float32)
        sample = {
            "ir": torch.from_numpy(ir.astype(np.float32, copy=False))[None],
            "row0": torch.tensor(y0 // self.stride),
            "x0": torch.tensor(x0),
        }
        for key in ("column", "valid", "edge"):
            step = self.stride  # at the output pixels
            sub = t[key][rows.start : rows.stop : step, cols.start : cols.stop : step]
            sample[key] = torch.from_numpy(np.array(sub))
        sample["column"] = torch.nan_to_num(sample["column"])  # invalid pixels are masked anyway
        return sample


class EpochSampler(Sampler[int]):
    """A seeded permutation of all frames per epoch (shuffles across and within shards), cut to whole
    global batches of `batch` samples, skipping the first `skip` samples of the first epoch it serves so
    a resumed run sees what an unbroken run would. With `world` ranks, rank r takes every world-th sample
    from the r-th (as torch's DistributedSampler), so the ranks' k-th batches of batch / world samples
    together hold the samples of a single process's k-th batch."""

    def __init__(self, n: int, seed: int, epoch: int = 0, skip: int = 0, batch: int = 1, rank: int = 0,
                 world: int = 1):
        self.n, self.seed, self.epoch, self.skip = n, seed, epoch, skip
        self.usable, self.rank, self.world = n - n % batch, rank, world

    def __iter__(self):
        g = torch.Generator().manual_seed(self.seed * 1_000_003 + self.epoch)
        order = torch.randperm(self.n, generator=g).tolist()
        return iter(order[self.skip + self.rank : self.usable : self.world])

    def __len__(self) -> int:
        return len(range(self.skip + self.rank, self.usable, self.world))


def make_loader(ds: FrameDataset, batch_size: int, epoch: int, skip: int, workers: int, rank: int = 0,
                world: int = 1) -> DataLoader:
    """Loader of rank `rank`'s share (batch_size / world per batch) of one epoch's global batches of
    batch_size samples (workers are recreated per epoch so they see ds.epoch)."""
    ds.epoch = epoch
    return DataLoader(
        ds, batch_size=batch_size // world, sampler=EpochSampler(len(ds), ds.seed, epoch, skip, batch_size,
                                                                  rank, world),
        num_workers=workers, drop_last=True, persistent_workers=False,
    )
