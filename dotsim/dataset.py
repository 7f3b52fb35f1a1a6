"""The dotsim dataset format: writer, reader, shards, checksums (specified in docs/FORMAT.md).

Layout::

    DATASET/index.json                      written by finalize_dataset (shards, counts, checksums)
    DATASET/dataset.json                    layout (scenes_per_shard), written with the first scene
    DATASET/<other files>                   dataset-level files, e.g. pattern.png (write_dataset_file)
    DATASET/shard_00000/shard.json          written by finalize_dataset (sha256 of every file)
    DATASET/shard_00000/scene_0000000/scene.json      metadata, written last (lists frame sha256)
    DATASET/shard_00000/scene_0000000/frame_0.exr     one EXR per frame, channels FRAME_CHANNELS

Integrity is a chain: index.json holds the sha256 of every shard.json, shard.json the sha256 of
every file of its scenes, scene.json the sha256 of its frames. Every write goes to a temporary
name (``.tmp-...-<pid>``) and is renamed into place, so a reader never sees half a file or half a
scene; a rerun tells complete scenes (the final directory exists) from leftovers (``.tmp-*``).
"""

from __future__ import annotations

import functools
import hashlib
import io
import json
import os
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from dotsim import __version__ as DOTSIM_VERSION

if TYPE_CHECKING:
    from dotsim.patterns import DotPattern

FORMAT_VERSION = "1.0"
DEFAULT_SCENES_PER_SHARD = 100
# Lossless; chosen over PIZ by bench/read_shards.py --compression (numbers in docs/FORMAT.md).
EXR_COMPRESSION = "ZIP_COMPRESSION"

# Stored dtype per channel (what read_frame returns). Why each was chosen: docs/FORMAT.md.
# Masks are uint8 in memory and UINT (32-bit) in the EXR: EXR has no 8-bit pixel type.
FRAME_CHANNELS: dict[str, np.dtype] = {
    "ir": np.dtype(np.float16),
    "ambient": np.dtype(np.float16),
    "flood": np.dtype(np.float16),
    "depth": np.dtype(np.float32),
    "visibility": np.dtype(np.uint8),
    "edge": np.dtype(np.uint8),
    "projector_column": np.dtype(np.float32),
    "disparity": np.dtype(np.float32),
}
MASK_CHANNELS = ("visibility", "edge")
# Scene meta keys the writer requires from the caller; the writer adds format_version,
# dotsim_version, scene_index, frame_count, channels and frames itself.
REQUIRED_META_KEYS = ("split", "rig", "pattern", "poses")
WRITER_META_KEYS = ("format_version", "dotsim_version", "scene_index", "frame_count", "channels", "frames")

INDEX_FILE = "index.json"
LAYOUT_FILE = "dataset.json"
SHARD_FILE = "shard.json"
SCENE_FILE = "scene.json"
PATTERN_FILE = "pattern.png"
TMP_PREFIX = ".tmp-"
_SCENE_DIR_RE = re.compile(r"^scene_(\d{7,})$")
_SHARD_DIR_RE = re.compile(r"^shard_(\d{5,})$")
_TMP_PID_RE = re.compile(r"-(\d+)$")


class FormatError(ValueError):
    """A dataset file is missing, malformed, of an unknown version, or fails its checksum."""


# ----------------------------------------------------------------------------- names and paths


def shard_name(shard_index: int) -> str:
    return f"shard_{shard_index:05d}"


def scene_name(scene_index: int) -> str:
    return f"scene_{scene_index:07d}"


def frame_name(frame_index: int) -> str:
    return f"frame_{frame_index}.exr"


def scene_dir(dataset_dir: str | os.PathLike, scene_index: int, scenes_per_shard: int) -> Path:
    """Final directory of scene `scene_index`: shard scene_index // scenes_per_shard."""
    return Path(dataset_dir) / shard_name(scene_index // scenes_per_shard) / scene_name(scene_index)


def pattern_path(dataset_dir: str | os.PathLike) -> Path:
    """Where the dataset's projector pattern image lives (written by store_pattern)."""
    return Path(dataset_dir) / PATTERN_FILE


def store_pattern(dataset_dir: str | os.PathLike, pattern: DotPattern) -> Path:
    """Write DATASET/pattern.png (16-bit PNG, atomically) unless it is there; returns its path.

    A rerun that finds the file keeps it when it holds the same pattern (same DotPattern.sha256)
    and raises FormatError naming the file when it holds another one: one dataset, one pattern.
    """
    from dotsim.patterns import PatternError, load_pattern  # OpenCV/SciPy: dataset readers need neither

    path = pattern_path(dataset_dir)
    if path.exists():
        try:
            stored = load_pattern(path)
        except PatternError as error:
            raise FormatError(str(error)) from None
        if stored.sha256 != pattern.sha256:
            raise FormatError(
                f"{path}: holds another pattern ({stored.width}x{stored.height}, "
                f"sha256 {stored.sha256[:12]}) than {pattern.source} ({pattern.width}x{pattern.height}, "
                f"sha256 {pattern.sha256[:12]}); a dataset has one pattern")
    else:
        pattern.save_png(path)
    return path


def pattern_entry(pattern: DotPattern) -> dict:
    """scene.json's `pattern` entry for the pattern stored by store_pattern."""
    return {"source": pattern.source, "sha256": pattern.sha256, "file": PATTERN_FILE,
            "width": pattern.width, "height": pattern.height, "params": pattern.params}


# ----------------------------------------------------------------------------- atomic files


def _tmp_name(final_name: str) -> str:
    return f"{TMP_PREFIX}{final_name}-{os.getpid()}"


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write `data` to `path` via a temporary sibling and os.replace, so readers see all or nothing."""
    path = Path(path)
    tmp = path.with_name(_tmp_name(path.name))
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    return path


def _json_bytes(obj) -> bytes:
    # allow_nan=False: NaN/inf are not JSON; a clear error beats a file other readers reject.
    return (json.dumps(obj, indent=2, sort_keys=True, allow_nan=False) + "\n").encode()


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def write_dataset_file(dataset_dir: str | os.PathLike, name: str, data: bytes) -> Path:
    """Atomically write a dataset-level file (e.g. pattern.png); finalize_dataset checksums it."""
    if "/" in name or name.startswith(".") or name in (INDEX_FILE, LAYOUT_FILE):
        raise FormatError(f"dataset-level file name {name!r} is not allowed (plain name, not "
                          f"hidden, not {INDEX_FILE} or {LAYOUT_FILE})")
    Path(dataset_dir).mkdir(parents=True, exist_ok=True)
    return atomic_write_bytes(Path(dataset_dir) / name, data)


# ----------------------------------------------------------------------------- versions


def check_format_version(version, where: str | os.PathLike) -> None:
    """Refuse a format version whose major part differs from ours (minor differences are tolerated)."""
    if not isinstance(version, str) or not re.fullmatch(r"\d+\.\d+", version):
        raise FormatError(f"{where}: format_version {version!r} is not of the form 'MAJOR.MINOR'")
    major = version.split(".")[0]
    ours = FORMAT_VERSION.split(".")[0]
    if major != ours:
        raise FormatError(f"{where}: format_version {version} has major version {major}; this dotsim "
                          f"({DOTSIM_VERSION}) reads major version {ours} only (format {FORMAT_VERSION})")


def _load_json(path: Path, data: bytes | None = None) -> dict:
    try:
        if data is None:
            data = path.read_bytes()
        obj = json.loads(data)
    except FileNotFoundError:
        raise FormatError(f"{path}: missing") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise FormatError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(obj, dict):
        raise FormatError(f"{path}: expected a JSON object, found {type(obj).__name__}")
    return obj


def _require(obj: dict, key: str, kind, where) -> object:
    if key not in obj:
        raise FormatError(f"{where}: missing key {key!r}")
    if not isinstance(obj[key], kind):
        raise FormatError(f"{where}: key {key!r} must be {getattr(kind, '__name__', kind)}, "
                          f"found {type(obj[key]).__name__}")
    return obj[key]


# ----------------------------------------------------------------------------- frames (EXR)


def camera_size(meta: dict, where="scene meta") -> tuple[int, int]:
    """(height, width) of the camera image from a scene's rig dict (Rig.to_dict())."""
    try:
        cam = meta["rig"]["camera"]
        h, w = cam["height"], cam["width"]
    except (KeyError, TypeError):
        raise FormatError(f"{where}: rig.camera.width/height missing") from None
    if not (isinstance(h, int) and isinstance(w, int) and h > 0 and w > 0):
        raise FormatError(f"{where}: rig.camera size must be positive integers, found {w} x {h}")
    return h, w


def _to_stored(name: str, array, where: str) -> np.ndarray:
    """Convert a caller's array to the stored dtype of channel `name`, refusing lossy surprises."""
    a = np.asarray(array)
    dtype = FRAME_CHANNELS[name]
    if a.ndim != 2:
        raise FormatError(f"{where}: channel {name!r} must be 2-D (H, W), found shape {a.shape}")
    if name in MASK_CHANNELS:
        if a.dtype == bool:
            return a.astype(np.uint32)
        if not np.issubdtype(a.dtype, np.integer) or not np.isin(a, (0, 1)).all():
            raise FormatError(f"{where}: mask channel {name!r} must be bool or integers 0/1, "
                              f"found dtype {a.dtype} with values outside {{0, 1}}")
        return a.astype(np.uint32)
    if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise FormatError(f"{where}: channel {name!r} must be numeric, found dtype {a.dtype}")
    with np.errstate(over="ignore"):  # overflow is reported below, naming the channel
        stored = a.astype(dtype)
    overflow = np.isfinite(a) & ~np.isfinite(stored)
    if overflow.any():
        raise FormatError(f"{where}: channel {name!r} has {int(overflow.sum())} finite values beyond "
                          f"the {dtype} range (max {float(np.nanmax(np.abs(a)))}; {dtype} max "
                          f"{float(np.finfo(dtype).max)})")
    if name == "depth":
        bad = np.isnan(stored) | (stored <= 0)
        if bad.any():
            raise FormatError(f"{where}: depth must be > 0 metres or +inf (no hit); {int(bad.sum())} "
                              f"pixels are NaN or <= 0")
    return stored


def _frame_pixels(frame: dict, channels: tuple[str, ...], shape: tuple[int, int], where: str) -> dict:
    """Validate a frame dict and convert it to {channel: contiguous array in EXR pixel dtype}."""
    missing = [c for c in channels if c not in frame]
    unknown = [c for c in frame if c not in FRAME_CHANNELS]
    if missing:
        raise FormatError(f"{where}: missing channel(s) {missing}; required: {list(channels)}")
    if unknown:
        raise FormatError(f"{where}: unknown channel(s) {unknown}; known: {list(FRAME_CHANNELS)}")
    extra = [c for c in frame if c not in channels]
    if extra:
        raise FormatError(f"{where}: channel(s) {extra} not in this scene's channel list {list(channels)}")
    pixels = {}
    for name in channels:
        stored = _to_stored(name, frame[name], where)
        if stored.shape != shape:
            raise FormatError(f"{where}: channel {name!r} has shape {stored.shape}, the rig camera is "
                              f"{shape} (height, width)")
        pixels[name] = np.ascontiguousarray(stored)
    return pixels


def write_frame_file(path: str | os.PathLike, frame: dict, shape: tuple[int, int],
                     channels: tuple[str, ...] | None = None, compression: str = EXR_COMPRESSION,
                     where: str = "frame") -> str:
    """Write one frame EXR at `path` (write_scene calls it inside its temp dir); return its sha256.

    compression: an OpenEXR compression name (docs/FORMAT.md and bench/read_shards.py compare them).
    """
    import OpenEXR

    channels = tuple(FRAME_CHANNELS) if channels is None else tuple(channels)
    pixels = _frame_pixels(frame, channels, shape, where)
    header = {"compression": getattr(OpenEXR, compression), "type": OpenEXR.scanlineimage,
              "dotsim_format_version": FORMAT_VERSION}
    OpenEXR.File(header, pixels).write(str(path))
    return sha256_file(path)


def _decode_frame(data: bytes, path: Path, channels, shape) -> dict[str, np.ndarray]:
    import OpenEXR

    try:
        exr = OpenEXR.File(io.BytesIO(data), separate_channels=True)
    except Exception as e:  # OpenEXR raises plain RuntimeError/ValueError for corrupt files
        raise FormatError(f"{path}: not a readable OpenEXR file ({e})") from None
    version = exr.header().get("dotsim_format_version")
    if version is not None:
        check_format_version(version, path)
    stored = exr.channels()
    source = "height, width of the rig camera in scene.json"
    if channels is None:
        channels = [c for c in FRAME_CHANNELS if c in stored]
        if not channels:
            raise FormatError(f"{path}: no dotsim channel found (has {sorted(stored)}; "
                              f"known: {list(FRAME_CHANNELS)})")
    missing = [c for c in channels if c not in stored]
    if missing:
        raise FormatError(f"{path}: missing channel(s) {missing}; file has {sorted(stored)}")
    out = {}
    for name in channels:
        if name not in FRAME_CHANNELS:
            raise FormatError(f"{path}: unknown channel {name!r}; known: {list(FRAME_CHANNELS)}")
        a = stored[name].pixels
        if shape is None:
            shape, source = a.shape, f"the shape of channel {name!r}"
        if a.shape != tuple(shape):
            raise FormatError(f"{path}: channel {name!r} has shape {a.shape}, expected {tuple(shape)} "
                              f"({source})")
        want = FRAME_CHANNELS[name]
        if name in MASK_CHANNELS:
            if a.dtype != np.uint32:
                raise FormatError(f"{path}: mask channel {name!r} stored as {a.dtype}, expected UINT")
            if a.max(initial=0) > 1:
                raise FormatError(f"{path}: mask channel {name!r} has values other than 0/1")
            a = a.astype(np.uint8)
        elif a.dtype != want:
            raise FormatError(f"{path}: channel {name!r} stored as {a.dtype}, expected {want}")
        out[name] = a
    return out


# ----------------------------------------------------------------------------- writing


def _layout(dataset_dir: Path, scenes_per_shard: int) -> None:
    """Record scenes_per_shard on first write; refuse to mix layouts in one dataset."""
    path = dataset_dir / LAYOUT_FILE
    if not path.exists():
        atomic_write_bytes(path, _json_bytes({"format_version": FORMAT_VERSION,
                                              "scenes_per_shard": scenes_per_shard}))
    layout = read_layout(dataset_dir)
    if layout != scenes_per_shard:
        raise FormatError(f"{path}: dataset was started with scenes_per_shard={layout}, "
                          f"this write asks for {scenes_per_shard}")


def read_layout(dataset_dir: str | os.PathLike) -> int:
    """scenes_per_shard of an existing dataset (from dataset.json)."""
    path = Path(dataset_dir) / LAYOUT_FILE
    if not path.exists():
        raise FormatError(f"{path}: missing; write_scene creates it with the first scene, so "
                          f"{Path(dataset_dir)} holds no scenes written by dotsim")
    obj = _load_json(path)
    check_format_version(obj.get("format_version"), path)
    n = _require(obj, "scenes_per_shard", int, path)
    if n < 1:
        raise FormatError(f"{path}: scenes_per_shard must be >= 1, found {n}")
    return n


def write_scene(dataset_dir: str | os.PathLike, scene_index: int, meta: dict, frames: list[dict],
                scenes_per_shard: int = DEFAULT_SCENES_PER_SHARD,
                channels: tuple[str, ...] | None = None) -> Path:
    """Write one scene atomically and return its final directory.

    meta: JSON-safe dict with at least REQUIRED_META_KEYS ("rig" is Rig.to_dict(); its camera size
    is the required frame shape; "poses" has one 4x4 world_from_camera per frame). The writer adds
    format_version, dotsim_version, scene_index, frame_count, channels and frames (file + sha256).
    frames: one dict per frame, channel name -> (H, W) array, converted to FRAME_CHANNELS dtypes
    (masks: bool or 0/1 ints). channels: the channel set every frame carries (default: all of
    FRAME_CHANNELS; real captures without ground truth pass a subset, which must include "ir").
    The scene goes to a temp dir, scene.json last, then one rename: a crash leaves only a
    ``.tmp-*`` dir that remove_partial_scenes deletes.
    """
    dataset_dir = Path(dataset_dir)
    if not isinstance(scene_index, int | np.integer) or scene_index < 0:
        raise FormatError(f"scene_index must be a non-negative integer, found {scene_index!r}")
    scene_index = int(scene_index)
    if not isinstance(scenes_per_shard, int) or scenes_per_shard < 1:
        raise FormatError(f"scenes_per_shard must be a positive integer, found {scenes_per_shard!r}")
    where = f"scene {scene_index}"
    channels = tuple(FRAME_CHANNELS) if channels is None else tuple(channels)
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
    shape = camera_size(meta, f"{where} meta")

    final = scene_dir(dataset_dir, scene_index, scenes_per_shard)
    if final.exists():
        raise FormatError(f"{final}: scene already exists (check is_scene_complete before writing)")
    final.parent.mkdir(parents=True, exist_ok=True)
    _layout(dataset_dir, scenes_per_shard)
    tmp = final.parent / _tmp_name(final.name)
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir()
    try:
        frame_entries = []
        for k, frame in enumerate(frames):
            name = frame_name(k)
            sha = write_frame_file(tmp / name, frame, shape, channels, where=f"{where} frame {k}")
            frame_entries.append({"file": name, "sha256": sha})
        full_meta = {key: value for key, value in meta.items() if key not in WRITER_META_KEYS}
        full_meta.update(format_version=FORMAT_VERSION, dotsim_version=DOTSIM_VERSION,
                         scene_index=scene_index, frame_count=len(frames),
                         channels={c: FRAME_CHANNELS[c].name for c in channels}, frames=frame_entries)
        try:
            data = _json_bytes(full_meta)
        except (TypeError, ValueError) as e:
            raise FormatError(f"{where}: meta is not JSON-safe ({e})") from None
        (tmp / SCENE_FILE).write_bytes(data)
        os.rename(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
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


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return False  # our own leftovers are never in use by a live writer at resume time
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_partial_scenes(dataset_dir: str | os.PathLike, include_live: bool = False) -> list[Path]:
    """Delete ``.tmp-*`` leftovers (half-written scenes and JSON files) from crashed writers.

    Leftovers whose writer process (the pid suffix) is still running on this machine are kept
    unless include_live, so a resume never pulls files from under a concurrent worker.
    Returns the removed paths.
    """
    root = Path(dataset_dir)
    # Temp names live beside their final names: top level, shard dirs, and other first-level dirs
    # (e.g. the generator's logs/).
    candidates = list(root.glob(TMP_PREFIX + "*")) + list(root.glob("*/" + TMP_PREFIX + "*"))
    return _remove([p for p in sorted(candidates) if include_live or not _writer_alive(p)])


def _writer_alive(tmp: Path) -> bool:
    m = _TMP_PID_RE.search(tmp.name)
    return bool(m) and _pid_alive(int(m.group(1)))


def _remove(paths: list[Path]) -> list[Path]:
    """Delete each path (a folder with its content) and return them."""
    for p in paths:
        if p.is_dir():
            shutil.rmtree(p)
        else:
            p.unlink()
    return paths


def remove_partial_scenes_in_range(dataset_dir: str | os.PathLike, first: int, stop: int,
                                   scenes_per_shard: int) -> list[Path]:
    """Delete the ``.tmp-scene_*`` leftovers of scenes first .. stop-1, whatever wrote them.

    For a writer that owns a range of scenes while other machines write other ranges into the same
    dataset (a Slurm array task, a Ray run after a node died): pids of other machines mean nothing
    here, and only this range's writers (all finished or dead) can have left these. Lists one
    shard folder per shard of the range. Returns the removed paths.
    """
    found = []
    for shard_index in range(first // scenes_per_shard, (stop - 1) // scenes_per_shard + 1):
        for p in sorted((Path(dataset_dir) / shard_name(shard_index)).glob(TMP_PREFIX + "scene_*")):
            m = _SCENE_DIR_RE.match(_TMP_PID_RE.sub("", p.name[len(TMP_PREFIX):]))
            if m and first <= int(m.group(1)) < stop:
                found.append(p)
    return _remove(found)


def _numbered_dirs(folder: Path, name_re: re.Pattern) -> list[tuple[int, Path]]:
    """(number, path) of the sub-folders whose names match name_re (group 1 = the number), by number."""
    found = []
    for p in folder.iterdir():
        m = name_re.match(p.name)
        if m and p.is_dir():
            found.append((int(m.group(1)), p))
    return sorted(found)


def _scene_dirs(shard: Path) -> list[tuple[int, Path]]:
    return _numbered_dirs(shard, _SCENE_DIR_RE)


def _shard_dirs(root: Path) -> list[tuple[int, Path]]:
    return _numbered_dirs(root, _SHARD_DIR_RE)


def complete_scenes(dataset_dir: str | os.PathLike) -> list[tuple[int, Path]]:
    """(scene_index, path) of every complete scene on disk, sorted; needs no index.json, so it
    works on a dataset still being written (temp dirs are never listed)."""
    root = Path(dataset_dir)
    if not root.is_dir():
        return []
    return [(index, sdir) for _, shard in _shard_dirs(root) for index, sdir in _scene_dirs(shard)
            if (sdir / SCENE_FILE).is_file()]


def finalize_dataset(dataset_dir: str | os.PathLike) -> dict:
    """Checksum every complete scene and write shard.json per shard and index.json (atomically).

    Re-hashes every file (sha256) and refuses when a frame no longer matches the sha256 its
    scene.json recorded at write time, so corruption between writing and sealing is caught.
    Safe to rerun after more scenes were written. Returns the index dict.
    """
    root = Path(dataset_dir)
    if not root.is_dir():
        raise FormatError(f"{root}: dataset directory does not exist")
    scenes_per_shard = read_layout(root)
    shards = []
    totals = {"scenes": 0, "frames": 0}
    splits: dict[str, int] = {}
    for shard_index, shard in _shard_dirs(root):
        scenes = []
        for index, sdir in _scene_dirs(shard):
            if index // scenes_per_shard != shard_index:
                raise FormatError(f"{sdir}: scene {index} belongs in {shard_name(index // scenes_per_shard)} "
                                  f"(scenes_per_shard={scenes_per_shard})")
            if not (sdir / SCENE_FILE).is_file():
                raise FormatError(f"{sdir / SCENE_FILE}: missing (a scene dir without scene.json "
                                  f"was not written by write_scene)")
            scene_bytes = (sdir / SCENE_FILE).read_bytes()
            meta = parse_scene_meta(sdir / SCENE_FILE, scene_bytes)
            files = {SCENE_FILE: sha256_bytes(scene_bytes)}
            for entry in meta["frames"]:
                path = sdir / entry["file"]
                if not path.is_file():
                    raise FormatError(f"{path}: missing (listed in {SCENE_FILE})")
                sha = sha256_file(path)
                if sha != entry["sha256"]:
                    raise FormatError(f"{path}: sha256 {sha} differs from {entry['sha256']} recorded in "
                                      f"{SCENE_FILE} at write time (file changed or corrupt)")
                files[entry["file"]] = sha
            scenes.append({"scene_index": index, "name": sdir.name, "split": meta.get("split"),
                           "frame_count": meta["frame_count"], "files": files})
            splits[str(meta.get("split"))] = splits.get(str(meta.get("split")), 0) + 1
            totals["frames"] += meta["frame_count"]
        if not scenes:
            continue
        shard_json = {"format_version": FORMAT_VERSION, "dotsim_version": DOTSIM_VERSION,
                      "shard": shard.name, "scene_count": len(scenes), "scenes": scenes}
        data = _json_bytes(shard_json)
        atomic_write_bytes(shard / SHARD_FILE, data)
        shards.append({"name": shard.name, "scene_count": len(scenes), "sha256": sha256_bytes(data)})
        totals["scenes"] += len(scenes)
    extra_files = {p.name: sha256_file(p) for p in sorted(root.iterdir())
                   if p.is_file() and p.name != INDEX_FILE and not p.name.startswith(".")}
    index = {"format_version": FORMAT_VERSION, "dotsim_version": DOTSIM_VERSION,
             "scenes_per_shard": scenes_per_shard, "shards": shards,
             "scene_count": totals["scenes"], "frame_count": totals["frames"],
             "split_counts": splits, "files": extra_files}
    atomic_write_bytes(root / INDEX_FILE, _json_bytes(index))
    return index


# ----------------------------------------------------------------------------- reading


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
    """An opened, finalized dataset: its index.json and the scenes its shards list."""

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
    """Open a finalized dataset: read index.json, check versions and every shard.json's sha256.

    verify: also make read_scene/read_frame through this Dataset check file checksums.
    """
    root = Path(dataset_dir)
    if not root.is_dir():
        raise FormatError(f"{root}: dataset directory does not exist")
    index_path = root / INDEX_FILE
    if not index_path.exists():
        hint = ("it has scene shards: run finalize_dataset (or the generator to completion)"
                if any(_shard_dirs(root)) else "the directory holds no dotsim dataset")
        raise FormatError(f"{index_path}: missing; {hint}")
    index = _load_json(index_path)
    check_format_version(index.get("format_version"), index_path)
    if verify:
        for name, sha in index.get("files", {}).items():
            path = root / name
            if not path.is_file():
                raise FormatError(f"{path}: missing (listed in {index_path})")
            if sha256_file(path) != sha:
                raise FormatError(f"{path}: sha256 differs from the one in {index_path} (file changed "
                                  f"or corrupt; rerun finalize_dataset if it was rewritten on purpose)")
    refs = []
    for entry in _require(index, "shards", list, index_path):
        shard_path = root / entry["name"] / SHARD_FILE
        try:
            data = shard_path.read_bytes()
        except FileNotFoundError:
            raise FormatError(f"{shard_path}: missing (listed in {index_path})") from None
        if sha256_bytes(data) != entry["sha256"]:
            raise FormatError(f"{shard_path}: sha256 differs from the one in {index_path} "
                              f"(file changed or corrupt; rerun finalize_dataset if it was rewritten)")
        shard = _load_json(shard_path, data)
        check_format_version(shard.get("format_version"), shard_path)
        for s in _require(shard, "scenes", list, shard_path):
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
    shard = _load_json(shard_path)
    return {s["name"]: s["files"] for s in shard.get("scenes", [])}


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


def parse_scene_meta(path: Path, data: bytes) -> dict:
    """Validate scene.json bytes: JSON object, known major version, every required key, the
    channel list, the frame list, the rig camera size. Returns the dict."""
    meta = _load_json(path, data)
    check_format_version(meta.get("format_version"), path)
    for key in REQUIRED_META_KEYS + WRITER_META_KEYS:
        if key not in meta:
            raise FormatError(f"{path}: missing key {key!r}")
    channels = _require(meta, "channels", dict, path)
    unknown = [c for c in channels if c not in FRAME_CHANNELS]
    if unknown:
        raise FormatError(f"{path}: unknown channel(s) {unknown}; known: {list(FRAME_CHANNELS)}")
    frames = _require(meta, "frames", list, path)
    if len(frames) != _require(meta, "frame_count", int, path) or not all(
            isinstance(e, dict) and isinstance(e.get("file"), str) and isinstance(e.get("sha256"), str)
            for e in frames):
        raise FormatError(f"{path}: 'frames' must list frame_count entries {{file, sha256}}")
    camera_size(meta, path)
    return meta


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
        shape = camera_size(meta, path.parent / SCENE_FILE)
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
    return _decode_frame(data, path, channels, shape)


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
