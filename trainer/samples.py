"""What the network is fed, as torch datasets: training samples (IR crops with the GT projector column
at the network's output resolution: half, or full with [model] stride 1), and whole frames streamed from
any source (`Frames`).

A sample keeps the identity of the network's lines: crops start on full-resolution rows that are
multiples of the network's stride and carry their first output row (`row0`) and column (`x0`), so the
per-line weights see the rows they are meant for. The targets are read at the full-resolution pixels
the outputs sit on, (stride i, stride j) of the crop (trainer/model.py), so no target is interpolated
unless [data] slant resamples the crop as the pattern would look on a tilted plane (its rows stretched,
each row shifted against the next). Augmentations (gain, noise, vertical jitter, crops around near
pixels, slant) draw from an RNG keyed by (seed, epoch, frame index): the same sample comes out in any
worker and after a resume.
GigaDepth's recipe is here as [data] options: full frames (crop sizes 0), its uniform noise of random
amplitude, its edge mask (Sobel(disparity), dilated by an ellipse); [data] near_share draws a share of
the crops around pixels nearer than near_depth.

`Frames(source)` is a torch IterableDataset that yields one dict per frame of a dataset folder or of
`dotsim export`'s shards (dotsim.shards.reader.resolve names the forms): the channels as numpy arrays
(as dotsim.dataset.read_frame returns them), plus `key`, `scene_index`, `frame_index`, `split` and
`meta` (the scene.json dict: rig, pattern, poses; a SceneMeta). It needs no trainer config, and
PyTorch's default collate batches it (the channels as tensors, `meta` as a list: collate_meta):

    from torch.utils.data import DataLoader
    from trainer.samples import Frames
    loader = DataLoader(Frames("data/train.wds", channels=("ir", "depth")), batch_size=4, num_workers=4)

Its work is split first over ranks (torch.distributed's, or the RANK and WORLD_SIZE environment
variables), then over the DataLoader's workers: shards for shard sources, frames for a folder.
"""

from __future__ import annotations

import os
from collections.abc import Iterator

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, Sampler
from torch.utils.data._utils.collate import default_collate_fn_map

from dotsim import dataset as ds
from dotsim.frame_source import FrameRef
from dotsim.masks import disparity_edge_mask
from dotsim.rig.geometry import Rig, disparity_to_depth
from dotsim.shards.format import sample_key
from dotsim.shards.reader import (
    decode_sample,
    iter_tar_samples,
    open_shard,
    resolve,
)
from trainer.config import DataConfig

TRAIN_CHANNELS = ("ir", "visibility", "edge", "projector_column")


class DataError(ValueError):
    """The data cannot be used with this configuration or checkpoint (the data source's own errors:
    dotsim.frame_source.SourceError)."""


def frame_targets(frame: dict[str, np.ndarray], rig: Rig, cfg: DataConfig | None = None
                  ) -> dict[str, np.ndarray]:
    """Full-resolution arrays of one frame: ir (float32), column (normalised by the projector width,
    nan where invalid), valid (pattern visible, column finite and inside the projector image), edge
    (the stored mask, or with [data] edge_threshold GigaDepth's from the frame's disparity) and, with
    [data] near_share, near (the flat indices of the valid pixels nearer than near_depth); with [data]
    slant, disparity (nan where invalid)."""
    column = frame["projector_column"].astype(np.float32) / rig.projector.width
    valid = (frame["visibility"] > 0) & np.isfinite(column) & (column >= 0) & (column <= 1)
    edge = frame["edge"]
    if cfg is not None and cfg.edge_threshold > 0:
        edge = disparity_edge_mask(frame["disparity"], cfg.edge_threshold, cfg.edge_radius)
    targets = {
        "ir": frame["ir"].astype(np.float32),
        "column": np.where(valid, column, np.nan).astype(np.float32),
        "valid": valid,
        "edge": edge.astype(np.float32),
    }
    if cfg is not None and cfg.slant > 0:
        targets["disparity"] = np.where(valid, frame["disparity"], np.nan).astype(np.float32)
    if cfg is not None and cfg.near_share > 0:
        with np.errstate(invalid="ignore", divide="ignore"):
            depth = disparity_to_depth(frame["disparity"].astype(np.float64), rig)
        targets["near"] = np.flatnonzero(valid & (depth < cfg.near_depth)).astype(np.int64)
    return targets


def needed_channels(cfg: DataConfig) -> tuple[str, ...]:
    """The channels training reads: TRAIN_CHANNELS, and the disparity where [data] options need it."""
    return TRAIN_CHANNELS + (("disparity",) if cfg.edge_threshold > 0 or cfg.near_share > 0 or cfg.slant > 0
                             else ())


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
        t = frame_targets(self.frames[i].read(needed_channels(self.cfg)), self.rig, self.cfg)
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
            if self.cfg.near_share > 0 and rng.random() < self.cfg.near_share and len(t["near"]):
                y0, x0 = self.crop_around(int(t["near"][rng.integers(len(t["near"]))]), h, w)
            j = self.cfg.vertical_jitter
            jitter = int(np.clip(rng.integers(-j, j + 1), -y0, h - self.crop_h - y0)) if j else 0
        rows = slice(y0 + jitter, y0 + jitter + self.crop_h)
        scale, shear = self.tilt(t["disparity"][rows, x0 : x0 + self.crop_w], rng) if (
            self.augment and self.cfg.slant > 0) else (1.0, 0.0)
        x0, source_columns = stretched_columns(x0, self.crop_w, w, scale)
        source_columns = source_columns + shear * (np.arange(self.crop_h) - (self.crop_h - 1) / 2)[:, None]
        ir = resample_columns(t["ir"][rows], source_columns)
        if self.augment:
            ir = ir * rng.uniform(*self.cfg.intensity_scale)
            if self.cfg.noise_std > 0:
                ir = ir + rng.normal(0.0, self.cfg.noise_std, ir.shape).astype(np.float32)
            if self.cfg.uniform_noise > 0:
                amplitude = rng.uniform() * self.cfg.uniform_noise
                ir = ir + (rng.random(ir.shape) * amplitude).astype(np.float32)
        sample = {
            "ir": torch.from_numpy(ir.astype(np.float32, copy=False))[None],
            "row0": torch.tensor(y0 // self.stride),
            "x0": torch.tensor(x0),
        }
        at_outputs = {k: t[k][rows.start : rows.stop : self.stride] for k in ("column", "valid", "edge")}
        targets = resample_targets(at_outputs, source_columns[:: self.stride, :: self.stride])
        sample.update({key: torch.from_numpy(a) for key, a in targets.items()})
        sample["column"] = torch.nan_to_num(sample["column"])  # invalid pixels are masked anyway
        return sample

    def tilt(self, disparity: np.ndarray, rng: np.random.Generator) -> tuple[float, float]:
        """(stretch, shear) of [data] slant for a crop of this GT disparity: a plane at its median disparity
        tilted by angles drawn in [-slant, slant] (tilted_plane); none for a crop without disparity or,
        with slant_depth, one whose median depth is not nearer than it."""
        along, down = rng.uniform(-self.cfg.slant, self.cfg.slant, 2)
        found = disparity[np.isfinite(disparity) & (disparity > 0)]
        if not len(found):
            return 1.0, 0.0
        d, limit = float(np.median(found)), self.cfg.slant_depth
        if limit and float(disparity_to_depth(np.float64(d), self.rig)) >= limit:
            return 1.0, 0.0
        return tilted_plane(d, self.rig.camera.fx, along, down)

    def crop_around(self, pixel: int, h: int, w: int) -> tuple[int, int]:
        """(y0, x0) of the crop centred on flat pixel index `pixel` of an h x w frame, moved inside the
        frame, its first row a multiple of the stride (so the pixel may sit a row off the centre)."""
        py, px = divmod(pixel, w)
        y = min(max(py - self.crop_h // 2, 0), h - self.crop_h)
        return self.stride * (y // self.stride), min(max(px - self.crop_w // 2, 0), w - self.crop_w)


def tilted_plane(disparity: float, f: float, along: float, down: float) -> tuple[float, float]:
    """(stretch, shear) of the pattern on a plane at `disparity` px (focal length f px) tilted by `along`
    degrees about the vertical axis and `down` degrees about the horizontal one, against the plane facing
    the camera. A plane's disparity is linear in the pixel: d(u) = d (1 + tan(along) (u - u0) / f), so it
    changes by g = d tan(along) / f px a column, and the pattern, at column u - d(u), is stretched along
    the rows by 1 / (1 - g); down the columns each row shifts by d tan(down) / f px against the next.
    Far surfaces hardly change: at 2 px of disparity (the Table 2 camera's 5.4 m) even 80 degrees stretch
    the rows by 2.7 %.

    >>> [round(x, 4) for x in tilted_plane(20.0, 400.0, 45.0, 0.0)]
    [1.0526, 0.0]
    >>> [round(x, 4) for x in tilted_plane(2.0, 400.0, 80.0, -45.0)]
    [1.0292, -0.005]
    """
    along, down = np.radians(along), np.radians(down)
    return float(1 / (1 - disparity * np.tan(along) / f)), float(disparity * np.tan(down) / f)


def stretched_columns(x0: int, crop_w: int, w: int, scale: float) -> tuple[int, np.ndarray]:
    """A crop of crop_w columns of a w-column frame starting at x0, stretched `scale` times about its
    centre: (the stretched crop's first column, moved inside the frame; the frame column, fractional,
    each crop column shows): how a surface slanted in depth shows the pattern (tilted_plane). The crop
    claims the columns x0 .. x0 + crop_w - 1 for the network's feasible classes; off the centre they sit
    up to (1 - 1 / scale) crop_w / 2 px from the columns they show. scale 1: x0 .. x0 + crop_w - 1.

    >>> stretched_columns(10, 4, 100, 1.0)
    (10, array([10., 11., 12., 13.]))
    >>> stretched_columns(10, 4, 100, 2.0)[1]
    array([10.75, 11.25, 11.75, 12.25])
    """
    offsets = np.arange(crop_w) - (crop_w - 1) / 2
    reach = (crop_w - 1) / 2 / scale
    centre = float(np.clip(x0 + (crop_w - 1) / 2, min(reach, (w - 1) / 2), max(w - 1 - reach, (w - 1) / 2)))
    first = int(np.clip(round(centre - (crop_w - 1) / 2), 0, w - crop_w))
    return first, centre + offsets / scale


def _columns_of(rows: np.ndarray, columns: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(the left neighbour of each fractional column, inside rows (h, w); the weight of the right one;
    whether the column lies inside the frame), each shaped as rows read at `columns`: one column per crop
    column (w_crop,), or one per crop pixel (h, w_crop)."""
    w = rows.shape[1]
    left = np.clip(np.floor(columns).astype(np.int64), 0, w - 2)
    frac = np.broadcast_to(columns - left, (rows.shape[0], columns.shape[-1])).astype(np.float32)
    return np.broadcast_to(left, frac.shape), frac, (columns >= 0) & (columns <= w - 1)


def resample_columns(rows: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """rows (h, w) read at fractional `columns` (one per crop column, or one per pixel: (h, w_crop)),
    linearly interpolated (a copy; 0 outside the frame)."""
    left, frac, inside = _columns_of(rows, columns)
    if not frac.any():
        return np.take_along_axis(rows, left, axis=1)
    out = (np.take_along_axis(rows, left, axis=1) * (1 - frac)
           + np.take_along_axis(rows, left + 1, axis=1) * frac)
    return np.where(inside, out, 0).astype(rows.dtype)


def resample_targets(targets: dict[str, np.ndarray], columns: np.ndarray) -> dict[str, np.ndarray]:
    """The column, valid and edge targets (h, w) read at fractional `columns` as resample_columns reads
    them (copies): the column interpolated linearly between two valid neighbours off the edge mask (a
    smooth surface), else taken from the nearer neighbour (never a column between a foreground and its
    background); invalid outside the frame."""
    left, frac, inside = _columns_of(targets["column"], columns)
    if not frac.any():
        return {key: np.take_along_axis(a, left, axis=1) for key, a in targets.items()}
    (c0, v0, e0), (c1, v1, e1), (cn, vn, en) = (
        [np.take_along_axis(targets[k], at, axis=1) for k in ("column", "valid", "edge")]
        for at in (left, left + 1, np.where(frac < 0.5, left, left + 1)))
    smooth = v0 & v1 & (e0 == 0) & (e1 == 0)
    return {"column": np.where(smooth, c0 * (1 - frac) + c1 * frac, cn).astype(np.float32),
            "valid": np.where(smooth, True, vn) & inside, "edge": en}


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


class SceneMeta(dict):
    """The scene.json dict of a Frames sample. Its own type so that PyTorch's default collate batches
    it with collate_meta (registered in torch's default_collate_fn_map, PyTorch's documented way to
    extend default_collate, when this module is imported): scene.json holds null values and lists of
    per-scene lengths (objects, lights), which default_collate cannot stack."""


def collate_meta(batch, *, collate_fn_map=None) -> list[dict]:
    """The collate rule for SceneMeta: a batch's metadata as a list, one scene.json dict per sample,
    in the batch's order (default_collate uses it for the `meta` of Frames samples; a custom collate_fn
    can call it on [sample["meta"] for sample in samples])."""
    return list(batch)


default_collate_fn_map[SceneMeta] = collate_meta


def rank_and_world() -> tuple[int, int]:
    """This process's rank and the number of ranks: torch.distributed's when it is initialised,
    else RANK and WORLD_SIZE from the environment (torchrun sets them), else 0 and 1."""
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        return torch.distributed.get_rank(), torch.distributed.get_world_size()
    return int(os.environ.get("RANK", 0)), int(os.environ.get("WORLD_SIZE", 1))


def share(items: list, rank: int, world: int, worker: int, workers: int) -> list:
    """The items of (rank, worker): item i goes to the (i mod world*workers)-th of them, rank-major."""
    slot, slots = rank * workers + worker, world * workers
    return items[slot::slots]


class Frames(torch.utils.data.IterableDataset):
    """The frames of a source (see the module docstring) as dicts; `split` keeps one scene split,
    `channels` some channels (default all), `shuffle` with `seed` reorders the shards (or frames of a
    folder) per epoch (set_epoch). A sample's `meta` is a SceneMeta, so DataLoader(frames,
    batch_size=N) batches samples with PyTorch's default collate."""

    def __init__(self, source, channels=None, split: str | None = None, shuffle: bool = False,
                 seed: int = 0, rank: int | None = None, world: int | None = None, verify: bool = True):
        self.source = resolve(source)
        self.channels = None if channels is None else tuple(channels)
        self.split, self.shuffle, self.seed, self.verify = split, shuffle, seed, verify
        self.rank, self.world = rank, world
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def _units(self) -> list:
        if self.source.folder is None:
            units = list(self.source.shards)
        else:
            dataset = ds.open_dataset(self.source.folder, verify=self.verify)
            scenes = dataset.scenes if self.split is None else dataset.split(self.split)
            units = [(ref, k) for ref in scenes for k in range(ref.frame_count)]
        if self.shuffle:
            order = np.random.default_rng([self.seed, self.epoch]).permutation(len(units))
            units = [units[i] for i in order]
        rank, world = rank_and_world()
        rank = rank if self.rank is None else self.rank
        world = world if self.world is None else self.world
        info = torch.utils.data.get_worker_info()
        worker, workers = (0, 1) if info is None else (info.id, info.num_workers)
        return share(units, rank, world, worker, workers)

    def __iter__(self) -> Iterator[dict]:
        if self.source.folder is not None:
            for ref, k in self._units():
                meta = ds.read_scene_meta(ref.path, verify=self.verify)
                frame = ds.read_frame(ref.path / ds.frame_name(k), verify=self.verify, channels=self.channels,
                                      meta=meta)
                yield {"key": sample_key(ref.scene_index, k), "scene_index": ref.scene_index,
                       "frame_index": k, "split": meta["split"], "meta": SceneMeta(meta), **frame}
            return
        checksums = dict(self.source.checksums) if self.verify else {}
        for location in self._units():
            with open_shard(location, checksums) as stream:
                metas: dict[int, dict] = {}
                for key, files in iter_tar_samples(stream, location):
                    sample = decode_sample(key, files, self.channels, location, metas)
                    if self.split is None or sample["split"] == self.split:
                        yield {**sample, "meta": SceneMeta(sample["meta"])}
