"""Where everything of a dataset lives and what it is called; the format version; dataset.json.

Scene k lives in ``shard_{k // scenes_per_shard:05d}/scene_{k:07d}``; scenes_per_shard is fixed
by the first write into dataset.json. Names starting with ``.tmp-`` are unfinished writes.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

from dotsim.file_io import DuplicateKeyError, atomic_write_json, unique_keys
from dotsim.version import __version__ as DOTSIM_VERSION

# What this writer writes into dataset.json, shard.json and index.json; a frame and its scene.json
# record the oldest version that has their channels (dotsim.dataset.frames.frame_format_version).
FORMAT_VERSION = "2.3"
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
_SHA256_RE = re.compile(r"[0-9a-f]{64}")


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
        obj = json.loads(data, object_pairs_hook=unique_keys)
    except FileNotFoundError:
        raise FormatError(f"{path}: missing") from None
    except OSError as e:  # a folder where the file should be, no permission, ...
        raise FormatError(f"{path}: cannot read it ({e.strerror})") from None
    except DuplicateKeyError as e:
        raise FormatError(f"{path}: {e}; allowed: each key once") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise FormatError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(obj, dict):
        raise FormatError(f"{path}: expected a JSON object, found {type(obj).__name__}")
    return obj


def _is_sha256(value) -> bool:
    return isinstance(value, str) and _SHA256_RE.fullmatch(value) is not None


def _is_count(value) -> bool:
    return type(value) is int and value >= 0


def _is_checksums(value) -> bool:
    """{file name: sha256}, every name a plain name (no folder, no "..")."""
    return isinstance(value, dict) and all(
        isinstance(name, str) and name == Path(name).name and name not in ("", ".", "..") and _is_sha256(sha)
        for name, sha in value.items())


def _names(pattern: re.Pattern):
    return lambda value: isinstance(value, str) and pattern.fullmatch(value) is not None


def _entries(obj: dict, key: str, path: Path, fields: dict, what: str) -> list[dict]:
    """obj[key], a list of mappings each holding `fields` (name -> check); FormatError naming the
    first entry that does not, and what an entry is."""
    entries = require(obj, key, list, path)
    for k, entry in enumerate(entries):
        if not isinstance(entry, dict) or not all(name in entry and check(entry[name])
                                                  for name, check in fields.items()):
            text = json.dumps(entry)
            raise FormatError(f"{path}: {key}[{k}] = {text if len(text) <= 80 else text[:77] + '...'}; "
                              f"allowed: {what}")
    return entries


def parse_index(path: Path, data: bytes | None = None) -> dict:
    """index.json, checked before anything uses it: a dataset's (not an export's), a version this
    reader reads, `files` naming plain top-level files with their sha256, `shards` naming shard
    folders with theirs; FormatError naming the file and the key."""
    index = load_json(path, data)
    if "format" in index:  # an export (`dotsim export`) names its format; a dataset's index.json does not
        raise FormatError(f"{path}: format {index['format']!r} is not a dotsim dataset's index.json; "
                          "a folder of `dotsim export` shards is read by dotsim.shards.reader and "
                          "`dotsim train --data`")
    check_format_version(index.get("format_version"), path)
    if not _is_checksums(index.get("files", {})):
        raise FormatError(f"{path}: 'files' must map top-level file names to sha256 hex digests")
    _entries(index, "shards", path, {"name": _names(_SHARD_DIR_RE), "sha256": _is_sha256,
                                     "scene_count": _is_count},
             "{name: shard_NNNNN, sha256: 64 hex digits, scene_count: an integer >= 0}")
    return index


def parse_shard(path: Path, data: bytes | None = None) -> dict:
    """shard.json, checked before anything uses it: a version this reader reads, `scenes` each
    naming a scene folder, its index, frame count and {file name: sha256}; FormatError naming the
    file and the key."""
    shard = load_json(path, data)
    check_format_version(shard.get("format_version"), path)
    _entries(shard, "scenes", path, {"name": _names(_SCENE_DIR_RE), "scene_index": _is_count,
                                     "frame_count": _is_count, "files": _is_checksums},
             "{name: scene_NNNNNNN, scene_index and frame_count: integers >= 0, files: {file name: sha256}}")
    return shard


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
