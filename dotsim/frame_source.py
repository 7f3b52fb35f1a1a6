"""One data source: a dataset folder, `dotsim export` shards or their URLs, opened once.

`open_source(data, split)` resolves what `data` names (a dataset folder, an export folder, shard paths,
a brace pattern, URLs: dotsim.shards.reader.resolve; shards behind URLs are first copied to a local
cache, dotsim.shards.reader.stage_shards), lists the frames of `split` ("all": every scene) in the
dataset's order, checks that they share one rig, and returns a FrameSource: its frames (FrameRef:
read(channels), scene_meta()), its rig, its pattern (read once, checked against the rig's projector)
and the channels its frames store. Training, its validation, evaluation and the benches receive the
FrameSource, never the path: nothing resolves the data again. Both forms give the same frames in the
same order, so a seeded run sees the same samples from either.

Errors are SourceError (a FormatError): the data and what is wrong with it, the split asked for and
the splits present, the scene whose rig differs from the first one's, or the pattern file.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from dotsim.channels import CHANNEL, stored_channels
from dotsim.dataset import (
    FRAME_CHANNELS,
    FormatError,
    open_dataset,
    pattern_path,
    read_frame,
    read_scene_meta,
)
from dotsim.patterns import PatternError, load_pattern
from dotsim.rig.colour_camera import ColourCamera
from dotsim.rig.geometry import Rig
from dotsim.shards.format import PATTERN_NAME
from dotsim.shards.reader import (
    IndexedSample,
    Source,
    index_shards,
    is_url,
    read_indexed,
    resolve,
    stage_shards,
)


class SourceError(FormatError):
    """The data cannot be opened or used as asked (names the data and what is wrong)."""


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

    def channels(self) -> tuple[str, ...]:
        """The channels the frame stores, in the channel registry's order (an export's sample may hold
        fewer than its scene.json lists)."""
        if self.sample is None:
            stored = set(stored_channels(self.scene_meta().get("channels", ())))
        else:
            stored = {ext.split(".")[0] for ext, _, _ in self.sample.members}
        return tuple(name for name in FRAME_CHANNELS if name in stored)

    def scene_meta(self) -> dict:
        """The frame's scene.json dict."""
        if self.sample is None:
            return read_scene_meta(self.path.parent)
        return read_indexed(self.sample, channels=())["meta"]


@dataclass
class FrameSource:
    """The frames of one split of a data source, the one rig they share and the pattern they were
    rendered with. `name`: the data as given (for messages)."""

    name: str
    split: str
    frames: list[FrameRef]
    rig: Rig
    pattern_file: Path | None = field(repr=False)  # None: shards behind URLs (their pattern is not local)

    @cached_property
    def pattern(self) -> np.ndarray:
        """The projector pattern (read on first use, then kept), checked against the rig's projector."""
        if self.pattern_file is None:
            raise SourceError(f"{self.name}: shards behind URLs: stage them first (stage_shards) to find "
                              "their pattern")
        shape = (self.rig.projector.height, self.rig.projector.width)
        try:
            return load_pattern(self.pattern_file, shape).image
        except PatternError as e:
            raise SourceError(str(e)) from e

    @cached_property
    def channels(self) -> tuple[str, ...]:
        """The channels its (first) frame stores."""
        return self.frames[0].channels()

    @cached_property
    def colour_camera(self) -> ColourCamera | None:
        """The colour camera of its (first) frame's scene, whose images its `rgb` channel holds (scene.json
        `colour_camera`, docs/FORMAT.md), or None."""
        entry = self.frames[0].scene_meta().get("colour_camera")
        return None if entry is None else ColourCamera.from_dict(entry, f"{self.name}: colour_camera")

    @property
    def stereo(self) -> bool:
        """Whether its frames hold a stereo pair's second image (the channel registry's stereo channels)."""
        return any(CHANNEL[name].stereo for name in self.channels)

    def first(self, count: int) -> FrameSource:
        """The source cut to its first `count` frames (all of them when count is 0)."""
        if count <= 0:
            return self
        cut = copy.copy(self)  # keeps the pattern once read
        cut.frames = self.frames[:count]
        return cut

    def held_out(self, count: int, others: FrameSource, role: str) -> list[FrameRef]:
        """`count` validation frames spread evenly over this source (all when count is 0), checked to be
        none of the `role` ("training", "evaluated") frames of `others`: validation frames must be held
        out from the frames they judge; SourceError naming both sources otherwise."""
        frames = spread(self.frames, count)
        taken = {(f.path, f.scene_index, f.frame_index) for f in others.frames}
        if any((f.path, f.scene_index, f.frame_index) in taken for f in frames):
            raise SourceError(f"{self.name}: validation frames (split {self.split!r}) overlap the {role} "
                              f"frames of {others.name} (split {others.split!r}); give another split or "
                              "dataset")
        return frames


def spread(frames: list, count: int) -> list:
    """`count` items spread evenly over `frames` (all of them when there are fewer, or count is 0).

    >>> spread(list(range(10)), 3)
    [0, 4, 9]
    """
    if count <= 0 or len(frames) <= count:
        return list(frames)
    return [frames[k] for k in np.linspace(0, len(frames) - 1, count).round().astype(int)]


def open_source(data, split: str, cache_dir: str | Path | None = None) -> FrameSource:
    """The frames of the scenes of `split` ("all" for every scene) of `data`, with their rig and pattern
    (see the module docstring); shards behind URLs are first copied to `cache_dir`."""
    name = str(data)
    try:
        source = resolve(data)
        if source.folder is None:
            frames, rigs = _shard_frames(name, stage_shards(source, cache_dir), split)
        else:
            frames, rigs = _folder_frames(name, source.folder, split)
    except SourceError:
        raise
    except FormatError as e:
        raise SourceError(f"{name}: not a usable dotsim dataset: {e}") from e
    return FrameSource(name, split, frames, rigs.rig, _pattern_file(source))


def _pattern_file(source: Source) -> Path | None:
    """DATASET/pattern.png of a folder, else the pattern.png that `dotsim export` put beside the (local)
    shards; None for shards behind URLs."""
    if source.folder is not None:
        return pattern_path(source.folder)
    local = [s for s in source.shards if not is_url(s)]
    return Path(local[0]).parent / PATTERN_NAME if local else None


def _no_split_error(data: str, split: str, splits: list) -> SourceError:
    present: dict[str, int] = {}
    for s in splits:
        present[str(s)] = present.get(str(s), 0) + 1
    return SourceError(f"{data}: no scenes with split {split!r} "
                       f"(splits present: {present or 'none, empty dataset'}); choose one of those or 'all'")


class _OneRig:
    """The rig of the first scene seen; SourceError for a scene with another rig."""

    rig = first = None

    def check(self, meta: dict, where) -> None:
        scene_rig = Rig.from_dict(meta["rig"])
        if self.rig is None:
            self.rig, self.first = scene_rig, where
        elif scene_rig != self.rig:
            raise SourceError(f"{where}: its rig differs from {self.first}'s; a dataset for training has "
                              "one rig")


def _folder_frames(name: str, folder: Path, split: str) -> tuple[list[FrameRef], _OneRig]:
    dataset = open_dataset(folder)
    scenes = dataset.scenes if split == "all" else dataset.split(split)
    if not scenes:
        raise _no_split_error(name, split, [s.split for s in dataset.scenes])
    frames, rigs = [], _OneRig()
    for s in scenes:
        rigs.check(read_scene_meta(s.path), s.path)
        frames += [FrameRef(p, s.scene_index, k) for k, p in enumerate(s.frame_paths)]
    return frames, rigs


def _shard_frames(name: str, source: Source, split: str) -> tuple[list[FrameRef], _OneRig]:
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
        raise _no_split_error(name, split, list(splits.values()))
    return frames, rigs
