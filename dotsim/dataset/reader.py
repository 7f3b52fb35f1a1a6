"""Reading a dataset: open_dataset (index.json and every shard.json), scenes and frames.

With verify, every file read is checked against the sha256 one level up the chain
(index.json -> shard.json -> scene.json -> frames) on the bytes that are then decoded.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dotsim.dataset.frames import decode_frame
from dotsim.dataset.layout import (
    INDEX_FILE,
    SCENE_FILE,
    SHARD_FILE,
    FormatError,
    frame_name,
    parse_index,
    parse_shard,
    shard_dirs,
)
from dotsim.dataset.scene_meta import parse_scene_meta, scene_shapes
from dotsim.file_io import sha256_bytes, sha256_file


@dataclass(frozen=True)
class SceneRef:
    """A scene listed in a dataset index: where it is and the checksums of its files."""

    scene_index: int
    split: str | None
    path: Path
    frame_count: int
    files: dict = field(repr=False)

    @property
    def frame_paths(self) -> list[Path]:
        return [self.path / frame_name(k) for k in range(self.frame_count)]


@dataclass
class Scene:
    """A scene read from disk: its scene.json dict and its frames (channel -> array)."""

    path: Path
    meta: dict
    frames: list[dict[str, np.ndarray]]


@dataclass
class Dataset:
    """An opened, sealed dataset: its index.json and the scenes its shards list."""

    root: Path
    index: dict
    scenes: list[SceneRef]
    verify: bool = True

    def __len__(self) -> int:
        return len(self.scenes)

    def split(self, name: str) -> list[SceneRef]:
        return [s for s in self.scenes if s.split == name]

    def read_scene(self, i: int) -> Scene:
        return read_scene(self.scenes[i].path, verify=self.verify)


def open_dataset(dataset_dir: str | os.PathLike, verify: bool = True) -> Dataset:
    """Open a sealed dataset: read index.json, check versions and every shard.json's sha256.

    verify: also make read_scene/read_frame through this Dataset check file checksums.
    """
    root = Path(dataset_dir)
    if not root.is_dir():
        raise FormatError(f"{root}: dataset directory does not exist")
    index_path = root / INDEX_FILE
    if not index_path.exists():
        hint = ("it has scene shards: seal it with `dotsim seal DIR` (or run the generator to "
                "completion)" if any(shard_dirs(root)) else "the directory holds no dotsim dataset")
        raise FormatError(f"{index_path}: missing; {hint}")
    index = parse_index(index_path)
    if verify:
        for name, sha in index.get("files", {}).items():
            path = root / name
            if not path.is_file():
                raise FormatError(f"{path}: missing (listed in {index_path})")
            if sha256_file(path) != sha:
                raise FormatError(f"{path}: sha256 differs from the one in {index_path} (file changed "
                                  f"or corrupt; `dotsim verify DIR` lists what is wrong)")
    refs = []
    for entry in index["shards"]:
        shard_path = root / entry["name"] / SHARD_FILE
        try:
            data = shard_path.read_bytes()
        except FileNotFoundError:
            raise FormatError(f"{shard_path}: missing (listed in {index_path})") from None
        if sha256_bytes(data) != entry["sha256"]:
            raise FormatError(f"{shard_path}: sha256 differs from the one in {index_path} (a seal was "
                              f"interrupted or the file changed; `dotsim verify DIR --repair` mends it)")
        shard = parse_shard(shard_path, data)
        for s in shard["scenes"]:
            refs.append(SceneRef(scene_index=s["scene_index"], split=s.get("split"),
                                 path=root / entry["name"] / s["name"], frame_count=s["frame_count"],
                                 files=s["files"]))
    return Dataset(root=root, index=index, scenes=refs, verify=verify)


def _shard_checksum(scene_path: Path, file_name: str) -> str | None:
    """sha256 that the scene's shard.json lists for a file, or None when no shard.json lists it."""
    shard_path = scene_path.parent / SHARD_FILE
    try:
        stat = shard_path.stat()
    except FileNotFoundError:
        return None
    files = _shard_files(shard_path, stat.st_mtime_ns, stat.st_size).get(scene_path.name, {})
    return files.get(file_name)


@functools.lru_cache(maxsize=64)
def _shard_files(shard_path: Path, mtime_ns: int, size: int) -> dict[str, dict[str, str]]:
    """scene name -> {file: sha256} from a shard.json; cached per (path, mtime, size) because a
    trainer reads frames one by one and would otherwise parse the shard's JSON for each."""
    shard = parse_shard(shard_path)
    return {s["name"]: s["files"] for s in shard["scenes"]}


def read_scene_meta(scene_path: str | os.PathLike, verify: bool = True) -> dict:
    """Read and validate scene.json (version, required keys; its sha256 against shard.json if any)."""
    scene_path = Path(scene_path)
    path = scene_path / SCENE_FILE
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise FormatError(f"{path}: missing (not a scene directory, or an unfinished write)") from None
    if verify:
        expected = _shard_checksum(scene_path, SCENE_FILE)
        if expected is not None and sha256_bytes(data) != expected:
            raise FormatError(f"{path}: sha256 differs from the one in {scene_path.parent / SHARD_FILE}")
    return parse_scene_meta(path, data)


def read_frame(path: str | os.PathLike, verify: bool = True, channels=None,
               meta: dict | None = None) -> dict[str, np.ndarray]:
    """Read one frame EXR -> {channel: array in its FRAME_CHANNELS dtype} (masks as uint8 0/1).

    Inside a scene directory the scene.json beside the file says which channels must be present,
    the shape (rig camera size) and, with verify, the file's sha256. A lone frame EXR (no
    scene.json) yields whichever dotsim channels it holds, all of one shape. channels: read only
    these (default: all the scene lists). meta: the scene.json dict, when the caller has it.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise FormatError(f"{path}: missing") from None
    if meta is None and (path.parent / SCENE_FILE).exists():
        meta = read_scene_meta(path.parent, verify=verify)
    shape = None
    if meta is not None:
        shape = scene_shapes(meta, path.parent / SCENE_FILE)
        listed = list(meta["channels"])
        if channels is None:
            channels = listed
        else:
            not_listed = [c for c in channels if c not in listed]
            if not_listed:
                raise FormatError(f"{path}: channel(s) {not_listed} requested but the scene has {listed}")
        if verify:
            entry = next((e for e in meta["frames"] if e["file"] == path.name), None)
            if entry is None:
                raise FormatError(f"{path}: not listed in {path.parent / SCENE_FILE}")
            if sha256_bytes(data) != entry["sha256"]:
                raise FormatError(f"{path}: sha256 mismatch with {path.parent / SCENE_FILE} "
                                  f"(file changed or corrupt)")
    return decode_frame(data, path, channels, shape)


def read_scene(scene_path: str | os.PathLike, verify: bool = True, channels=None) -> Scene:
    """Read a scene directory: validated scene.json and every frame."""
    scene_path = Path(scene_path)
    meta = read_scene_meta(scene_path, verify=verify)
    frames = [read_frame(scene_path / e["file"], verify=verify, channels=channels, meta=meta)
              for e in meta["frames"]]
    return Scene(path=scene_path, meta=meta, frames=frames)


def dataset_summary(dataset_dir: str | os.PathLike) -> str:
    """One line describing a dataset: scenes, frames, shards, splits (from index.json)."""
    index = open_dataset(dataset_dir, verify=False).index
    splits = ", ".join(f"{k}: {v}" for k, v in sorted(index["split_counts"].items()))
    return (f"{dataset_dir}: {index['scene_count']} scenes, {index['frame_count']} frames in "
            f"{len(index['shards'])} shard(s) ({splits}); format {index['format_version']}, "
            f"dotsim {index['dotsim_version']}")
