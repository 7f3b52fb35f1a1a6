"""Writing scenes and dataset-level files, and what a resume needs: completeness and leftovers.

A scene is written into ``shard_NNNNN/.tmp-scene_KKKKKKK-<pid>/`` (frames, then scene.json last)
and renamed to ``scene_KKKKKKK`` in one step, so its final directory only ever exists complete.
A crash leaves only ``.tmp-*`` names, which remove_partial_scenes deletes on the next run
(remove_partial_scenes_in_range: those of one range of scenes, for a writer beside others).
"""

from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path

import numpy as np

from dotsim import __version__ as DOTSIM_VERSION
from dotsim.dataset.frames import (
    EXR_COMPRESSION,
    FRAME_CHANNELS,
    RENDERED_CHANNELS,
    encode_frame,
    frame_format_version,
)
from dotsim.dataset.layout import (
    DEFAULT_SCENES_PER_SHARD,
    INDEX_FILE,
    LAYOUT_FILE,
    SCENE_FILE,
    FormatError,
    frame_name,
    record_layout,
    scene_dir,
    shard_name,
)
from dotsim.dataset.scene_meta import REQUIRED_META_KEYS, WRITER_META_KEYS, scene_shapes
from dotsim.file_io import (
    TMP_PREFIX,
    atomic_write_bytes,
    disk_full_error,
    is_disk_full,
    json_bytes,
    make_folder,
    map_in_threads,
    sha256_bytes,
    temporary_name,
)
from dotsim.process_lifetime import is_zombie

_TMP_PID_RE = re.compile(r"-(\d+)$")
_TMP_SCENE_RE = re.compile(re.escape(TMP_PREFIX) + r"scene_(\d+)(-\d+)?$")


def write_dataset_file(dataset_dir: str | os.PathLike, name: str, data: bytes) -> Path:
    """Atomically write a dataset-level file (e.g. pattern.png); seal_dataset checksums it."""
    if "/" in name or name.startswith(".") or name in (INDEX_FILE, LAYOUT_FILE):
        raise FormatError(f"dataset-level file name {name!r} is not allowed (plain name, not "
                          f"hidden, not {INDEX_FILE} or {LAYOUT_FILE})")
    return atomic_write_bytes(make_folder(dataset_dir) / name, data)


def write_scene(dataset_dir: str | os.PathLike, scene_index: int, meta: dict, frames: list[dict],
                scenes_per_shard: int = DEFAULT_SCENES_PER_SHARD,
                channels: tuple[str, ...] | None = None, threads: int = 1,
                compression: str = EXR_COMPRESSION) -> Path:
    """Write one scene atomically and return its final directory.

    meta: JSON-safe dict with at least REQUIRED_META_KEYS ("rig" is Rig.to_dict(); its camera size
    is the required frame shape; "poses" has one 4x4 world_from_camera per frame). The writer adds
    format_version, dotsim_version, scene_index, frame_count, channels and frames (file + sha256).
    frames: one dict per frame, channel name -> (H, W) array (a colour camera's `rgb`: (h, w, 3) of the
    meta's "colour_camera" intrinsics), converted to FRAME_CHANNELS dtypes
    (masks: bool or 0/1 ints); `disparity` is derived from depth and the rig (it may be left out;
    one given must match it to float32 rounding). channels: the channel set every frame carries (default:
    RENDERED_CHANNELS; real captures without ground truth pass a subset, which must include "ir").
    The scene goes to a temp dir, scene.json last, then one rename: a crash leaves only a
    ``.tmp-*`` dir that remove_partial_scenes deletes. threads: frames encoded at once (the codec
    and numpy release the GIL; the bytes are the same whatever the number). compression: the frames'
    OpenEXR compression (a value of EXR_COMPRESSIONS; every one is lossless).
    """
    dataset_dir = Path(dataset_dir)
    if not isinstance(scene_index, int | np.integer) or scene_index < 0:
        raise FormatError(f"scene_index must be a non-negative integer, found {scene_index!r}")
    scene_index = int(scene_index)
    if not isinstance(scenes_per_shard, int) or scenes_per_shard < 1:
        raise FormatError(f"scenes_per_shard must be a positive integer, found {scenes_per_shard!r}")
    where = f"scene {scene_index}"
    channels = RENDERED_CHANNELS if channels is None else tuple(channels)
    if "ir" not in channels or any(c not in FRAME_CHANNELS for c in channels):
        raise FormatError(f"{where}: channels {list(channels)} must include 'ir' and be among "
                          f"{list(FRAME_CHANNELS)}")
    if not isinstance(meta, dict):
        raise FormatError(f"{where}: meta must be a dict, found {type(meta).__name__}")
    missing = [k for k in REQUIRED_META_KEYS if k not in meta]
    if missing:
        raise FormatError(f"{where}: meta lacks required key(s) {missing}; "
                          f"required: {list(REQUIRED_META_KEYS)}")
    if meta.get("scene_index", scene_index) != scene_index:
        raise FormatError(f"{where}: meta scene_index {meta['scene_index']} != {scene_index}")
    if not frames:
        raise FormatError(f"{where}: no frames")
    if len(meta["poses"]) != len(frames):
        raise FormatError(f"{where}: meta has {len(meta['poses'])} poses for {len(frames)} frames")
    shape = scene_shapes(meta, f"{where} meta")

    final = scene_dir(dataset_dir, scene_index, scenes_per_shard)
    if final.exists():
        raise FormatError(f"{final}: scene already exists (check is_scene_complete before writing)")
    # Encoded (and so validated) before anything is written: a bad frame leaves no trace on disk.
    def encode_and_hash(k: int) -> tuple[bytes, str]:
        data = encode_frame(frames[k], shape, channels, compression, where=f"{where} frame {k}",
                            rig=meta["rig"])
        return data, sha256_bytes(data)

    encoded, checksums = zip(*map_in_threads(encode_and_hash, range(len(frames)), threads), strict=True)
    full_meta = {key: value for key, value in meta.items() if key not in WRITER_META_KEYS}
    full_meta.update(format_version=frame_format_version(channels), dotsim_version=DOTSIM_VERSION,
                     scene_index=scene_index, frame_count=len(frames),
                     channels={c: FRAME_CHANNELS[c].name for c in channels},
                     frames=[{"file": frame_name(k), "sha256": sha} for k, sha in enumerate(checksums)])
    try:
        scene_json = json_bytes(full_meta)
    except (TypeError, ValueError) as e:
        raise FormatError(f"{where}: meta is not JSON-safe ({e})") from None

    make_folder(final.parent)
    record_layout(dataset_dir, scenes_per_shard)
    tmp = final.parent / temporary_name(final.name)
    if tmp.exists():
        shutil.rmtree(tmp)
    make_folder(tmp)
    try:
        for k, data in enumerate(encoded):
            atomic_write_bytes(tmp / frame_name(k), data)
        atomic_write_bytes(tmp / SCENE_FILE, scene_json)
        os.rename(tmp, final)
    except BaseException as error:
        shutil.rmtree(tmp, ignore_errors=True)
        if is_disk_full(error):
            raise disk_full_error(final, sum(map(len, encoded)) + len(scene_json)) from None
        raise
    return final


def is_scene_complete(dataset_dir: str | os.PathLike, scene_index: int,
                      scenes_per_shard: int = DEFAULT_SCENES_PER_SHARD) -> bool:
    """True when the scene's final directory exists with scene.json and every frame it lists.

    Cheap (no checksums): the final directory only ever appears by an atomic rename of a finished
    temp dir, so its existence is the completeness signal; the file checks catch manual damage.
    """
    d = scene_dir(dataset_dir, scene_index, scenes_per_shard)
    try:
        meta = json.loads((d / SCENE_FILE).read_bytes())
        return all((d / entry["file"]).is_file() for entry in meta["frames"])
    except (OSError, ValueError, KeyError, TypeError):
        return False


def remove_scene(dataset_dir: str | os.PathLike, scene_index: int,
                 scenes_per_shard: int = DEFAULT_SCENES_PER_SHARD) -> Path | None:
    """Delete a scene's final directory (a damaged scene, so that it is written again); returns it,
    or None when there is none. The folder is first renamed to a ``.tmp-`` name, so a crash
    half-way leaves a leftover remove_partial_scenes deletes, never half a scene under its name.
    """
    final = scene_dir(dataset_dir, scene_index, scenes_per_shard)
    if not final.exists():
        return None
    doomed = final.parent / temporary_name(final.name)
    if doomed.exists():
        shutil.rmtree(doomed)
    os.rename(final, doomed)
    shutil.rmtree(doomed)
    return final


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return False  # our own leftovers are never in use by a live writer at resume time
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return not is_zombie(pid)  # a killed writer not yet reaped writes nothing more


def leftovers(dataset_dir: str | os.PathLike, include_live: bool = False) -> list[Path]:
    """``.tmp-*`` leftovers (half-written scenes and files) of writers that are no longer running on
    this machine (the pid suffix), or of every writer with include_live, sorted."""
    root = Path(dataset_dir)
    # Temp names live beside their final names: top level, shard dirs, and other first-level dirs
    # (e.g. the generator's logs/).
    candidates = list(root.glob(TMP_PREFIX + "*")) + list(root.glob("*/" + TMP_PREFIX + "*"))
    found = []
    for p in sorted(candidates):
        m = _TMP_PID_RE.search(p.name)
        if include_live or not (m and _pid_alive(int(m.group(1)))):
            found.append(p)
    return found


def remove_partial_scenes(dataset_dir: str | os.PathLike, include_live: bool = False) -> list[Path]:
    """Delete the leftovers of crashed writers (see leftovers) and return their paths.

    Leftovers whose writer process is still running on this machine are kept unless
    include_live, so a resume never pulls files from under a concurrent worker.
    """
    return _remove(leftovers(dataset_dir, include_live))


def remove_partial_scenes_in_range(dataset_dir: str | os.PathLike, first: int, stop: int,
                                   scenes_per_shard: int = DEFAULT_SCENES_PER_SHARD) -> list[Path]:
    """Delete the ``.tmp-scene_*`` leftovers of scenes first .. stop-1, whatever wrote them.

    For a writer that owns a range of scenes while other machines write other ranges into the same
    dataset (a Slurm array task, a Ray run after a node died): pids of other machines mean nothing
    here, and only this range's writers (all finished or dead) can have left these. Lists one
    shard folder per shard of the range. Returns the removed paths.
    """
    found = []
    for shard_index in range(first // scenes_per_shard, (stop - 1) // scenes_per_shard + 1):
        shard = Path(dataset_dir) / shard_name(shard_index)
        for p in sorted(shard.glob(TMP_PREFIX + "scene_*")):
            m = _TMP_SCENE_RE.match(p.name)
            if m and first <= int(m.group(1)) < stop:
                found.append(p)
    return _remove(found)


def _remove(paths: list[Path]) -> list[Path]:
    """Delete each path (a folder with its content) and return them."""
    for p in paths:
        if p.is_dir():
            shutil.rmtree(p)
        else:
            p.unlink(missing_ok=True)
    return paths
