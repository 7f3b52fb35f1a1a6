"""Where everything of a dataset lives and what it is called; the format version; dataset.json.

Scene k lives in ``shard_{k // scenes_per_shard:05d}/scene_{k:07d}``; scenes_per_shard is fixed
by the first write into dataset.json. Names starting with ``.tmp-`` are unfinished writes.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

from dotsim import __version__ as DOTSIM_VERSION
from dotsim.file_io import atomic_write_json

# What this writer writes into dataset.json, shard.json and index.json; a frame and its scene.json
# record the oldest version that has their channels (dotsim.dataset.frames.frame_format_version).
FORMAT_VERSION = "2.1"
# Major versions this reader reads: 1.x (every channel stored, ZIP) and 2.x (docs/FORMAT.md "Versioning").
READABLE_MAJORS = ("1", "2")
DEFAULT_SCENES_PER_SHARD = 100

INDEX_FILE = "index.json"
LAYOUT_FILE = "dataset.json"
SHARD_FILE = "shard.json"
SCENE_FILE = "scene.json"
PATTERN_FILE = "pattern.png"
_SCENE_DIR_RE = re.compile(r"^scene_(\d{7,})$")
_SHARD_DIR_RE = re.compile(r"^shard_(\d{5,})$")


class FormatError(ValueError):
    """A dataset file is missing, malformed, of an unknown version, or fails its checksum."""


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
    """Where the dataset's projector pattern image lives (dotsim.pattern_store.store_pattern)."""
    return Path(dataset_dir) / PATTERN_FILE


def check_format_version(version, where: str | os.PathLike) -> None:
    """Refuse a format version of a major version this reader does not read (READABLE_MAJORS; any
    minor of those is read)."""
    if not isinstance(version, str) or not re.fullmatch(r"\d+\.\d+", version):
        raise FormatError(f"{where}: format_version {version!r} is not of the form 'MAJOR.MINOR'")
    major = version.split(".")[0]
    if major not in READABLE_MAJORS:
        raise FormatError(f"{where}: format_version {version} has major version {major}; this dotsim "
                          f"({DOTSIM_VERSION}) reads major versions {', '.join(READABLE_MAJORS)} "
                          f"(writes {FORMAT_VERSION})")


def load_json(path: Path, data: bytes | None = None) -> dict:
    """The JSON object in `path` (or in `data`, the file's bytes already read); FormatError naming it."""
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


def require(obj: dict, key: str, kind, where) -> object:
    """obj[key], refused (FormatError naming `where`) when missing or not of type `kind`."""
    if key not in obj:
        raise FormatError(f"{where}: missing key {key!r}")
    if not isinstance(obj[key], kind):
        raise FormatError(f"{where}: key {key!r} must be {getattr(kind, '__name__', kind)}, "
                          f"found {type(obj[key]).__name__}")
    return obj[key]


def record_layout(dataset_dir: Path, scenes_per_shard: int) -> None:
    """Record scenes_per_shard on first write; refuse to mix layouts in one dataset."""
    path = dataset_dir / LAYOUT_FILE
    if not path.exists():
        atomic_write_json(path, {"format_version": FORMAT_VERSION, "scenes_per_shard": scenes_per_shard})
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
    obj = load_json(path)
    check_format_version(obj.get("format_version"), path)
    n = require(obj, "scenes_per_shard", int, path)
    if n < 1:
        raise FormatError(f"{path}: scenes_per_shard must be >= 1, found {n}")
    return n


def _numbered_dirs(folder: Path, name_re: re.Pattern) -> list[tuple[int, Path]]:
    """(number, path) of the sub-folders whose names match name_re (group 1 = the number), by number."""
    found = []
    for p in folder.iterdir():
        m = name_re.match(p.name)
        if m and p.is_dir():
            found.append((int(m.group(1)), p))
    return sorted(found)


def scene_dirs(shard: Path) -> list[tuple[int, Path]]:
    """(scene_index, path) of the scene folders of a shard folder (complete or not), by index."""
    return _numbered_dirs(shard, _SCENE_DIR_RE)


def shard_dirs(root: Path) -> list[tuple[int, Path]]:
    """(shard_index, path) of the shard folders of a dataset, by index."""
    return _numbered_dirs(root, _SHARD_DIR_RE)


def complete_scenes(dataset_dir: str | os.PathLike) -> list[tuple[int, Path]]:
    """(scene_index, path) of every complete scene on disk, sorted; needs no index.json, so it
    works on a dataset still being written (temp dirs are never listed)."""
    root = Path(dataset_dir)
    if not root.is_dir():
        return []
    return [(index, sdir) for _, shard in shard_dirs(root) for index, sdir in scene_dirs(shard)
            if (sdir / SCENE_FILE).is_file()]
