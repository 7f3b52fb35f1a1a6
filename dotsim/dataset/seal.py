"""Sealing a dataset: shard.json per shard and index.json, the checksum chain readers verify.

`seal_dataset(DATASET)` seals what is on disk. Run it at any time, as often as wanted, from any
machine that sees the dataset: after one run, after each of many tasks that wrote scene ranges
in any order, or once at the end. It is incremental, so sealing a million scenes after a task
ends costs a listing and the small files, not a re-hash of every frame:

- a shard whose shard.json already lists exactly the complete scenes in its folder, with the
  same scene.json sha256, is kept (its frames are not read);
- a shard that gained, lost or changed scenes gets a new shard.json; only the scenes its old
  shard.json does not list (or lists with another scene.json) have their frames hashed, and a
  frame that differs from the sha256 its scene.json recorded at write time is refused;
- index.json is rebuilt from the shard.json files, then the seal is checked against the disk
  again; if a writer changed a shard meanwhile the seal is redone, so two seals running at once
  (or a seal racing a writer) still end with index.json true to the disk.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path

from dotsim import __version__ as DOTSIM_VERSION
from dotsim.dataset.layout import (
    FORMAT_VERSION,
    INDEX_FILE,
    SCENE_FILE,
    SHARD_FILE,
    FormatError,
    load_json,
    read_layout,
    scene_dirs,
    shard_dirs,
    shard_name,
)
from dotsim.dataset.scene_meta import parse_scene_meta
from dotsim.file_io import atomic_write_bytes, json_bytes, sha256_bytes, sha256_file

# A seal that finds the disk changed under it starts again; writers still running after this many
# rounds mean the caller should seal when they are done.
MAX_SEAL_ROUNDS = 5
_REPAIR_HINT = "run `dotsim verify DATASET --repair` to remove damaged scenes, then generate them again"


class DatasetChangingError(FormatError):
    """Writers kept changing the dataset while it was sealed; seal again when they are done."""


@dataclass
class SealResult:
    """What seal_dataset did: the index it wrote, the shards whose shard.json it (re)wrote, how
    many scenes it hashed the frames of, how many rounds it took, and the seconds it took."""

    index: dict
    shards_written: list[str] = field(default_factory=list)
    scenes_hashed: int = 0
    rounds: int = 0
    seconds: float = 0.0

    def line(self) -> str:
        return (f"sealed {self.index['scene_count']} scenes ({self.index['frame_count']} frames) in "
                f"{len(self.index['shards'])} shard(s): {len(self.shards_written)} shard.json written, "
                f"{self.scenes_hashed} scenes hashed, in {self.seconds:.2f} s")


def _read_shard(shard_path: Path) -> tuple[bytes, dict]:
    """(bytes, dict) of the shard.json there now; (b"", {}) when it is missing or unreadable (then
    every scene of the shard is hashed again)."""
    try:
        data = shard_path.read_bytes()
        shard = load_json(shard_path, data)
        if not isinstance(shard.get("scenes"), list):
            return b"", {}
        return data, shard
    except (OSError, FormatError):
        return b"", {}


def _scene_entry(sdir: Path, index: int, scene_bytes: bytes) -> dict:
    """shard.json entry of one scene, hashing its frames and comparing them with scene.json."""
    meta = parse_scene_meta(sdir / SCENE_FILE, scene_bytes)
    files = {SCENE_FILE: sha256_bytes(scene_bytes)}
    for entry in meta["frames"]:
        path = sdir / entry["file"]
        if not path.is_file():
            raise FormatError(f"{path}: missing (listed in {SCENE_FILE}); {_REPAIR_HINT}")
        sha = sha256_file(path)
        if sha != entry["sha256"]:
            raise FormatError(f"{path}: sha256 {sha} differs from {entry['sha256']} recorded in "
                              f"{SCENE_FILE} at write time (file changed or corrupt); {_REPAIR_HINT}")
        files[entry["file"]] = sha
    return {"scene_index": index, "name": sdir.name, "split": meta.get("split"),
            "frame_count": meta["frame_count"], "files": files}


@dataclass
class ShardSeal:
    """One shard's seal: its shard.json dict and the sha256 of that file's bytes, whether it was
    (re)written, and how many scenes had their frames hashed."""

    shard_json: dict
    sha256: str
    written: bool
    hashed: int


def seal_shard(shard: Path, shard_index: int, scenes_per_shard: int) -> ShardSeal | None:
    """Bring one shard's shard.json up to date with the complete scenes in its folder; None when
    the shard holds no scene (then it has no shard.json any more)."""
    path = shard / SHARD_FILE
    old_bytes, old_json = _read_shard(path)
    previous = {s.get("name"): s for s in old_json.get("scenes", []) if isinstance(s, dict)}
    scenes, hashed = [], 0
    for index, sdir in scene_dirs(shard):
        if index // scenes_per_shard != shard_index:
            raise FormatError(f"{sdir}: scene {index} belongs in {shard_name(index // scenes_per_shard)} "
                              f"(scenes_per_shard={scenes_per_shard})")
        try:
            scene_bytes = (sdir / SCENE_FILE).read_bytes()
        except FileNotFoundError:
            raise FormatError(f"{sdir / SCENE_FILE}: missing (a scene folder without scene.json is "
                              f"damaged); {_REPAIR_HINT}") from None
        old = previous.get(sdir.name)
        if old is not None and old.get("scene_index") == index and \
                old.get("files", {}).get(SCENE_FILE) == sha256_bytes(scene_bytes):
            scenes.append(old)
        else:
            scenes.append(_scene_entry(sdir, index, scene_bytes))
            hashed += 1
    if not scenes:
        path.unlink(missing_ok=True)  # every scene was removed (dotsim verify --repair)
        return None
    shard_json = {"format_version": FORMAT_VERSION, "dotsim_version": DOTSIM_VERSION,
                  "shard": shard.name, "scene_count": len(scenes), "scenes": scenes}
    # Compared as dicts, not as serialised bytes: indented JSON is slow to write in Python, and an
    # unchanged shard is the common case (index.json takes the sha256 of the bytes on disk).
    if shard_json == old_json:
        return ShardSeal(shard_json, sha256_bytes(old_bytes), False, 0)
    data = json_bytes(shard_json)
    atomic_write_bytes(path, data)
    return ShardSeal(shard_json, sha256_bytes(data), True, hashed)


def _read_bytes(path: Path) -> bytes | None:
    try:
        return path.read_bytes()
    except FileNotFoundError:
        return None


def _dataset_files(root: Path) -> dict[str, str]:
    """sha256 of every dataset-level file (regular top-level files but index.json and hidden ones)."""
    return {p.name: sha256_file(p) for p in sorted(root.iterdir())
            if p.is_file() and p.name != INDEX_FILE and not p.name.startswith(".")}


def build_index(root: Path, scenes_per_shard: int, shards: list[ShardSeal]) -> dict:
    """index.json's dict from the seals of the shards that hold scenes, in order."""
    splits: dict[str, int] = {}
    entries, scene_count, frame_count = [], 0, 0
    for seal in shards:
        shard = seal.shard_json
        for scene in shard["scenes"]:
            splits[str(scene.get("split"))] = splits.get(str(scene.get("split")), 0) + 1
            frame_count += scene["frame_count"]
        scene_count += shard["scene_count"]
        entries.append({"name": shard["shard"], "scene_count": shard["scene_count"], "sha256": seal.sha256})
    return {"format_version": FORMAT_VERSION, "dotsim_version": DOTSIM_VERSION,
            "scenes_per_shard": scenes_per_shard, "shards": entries, "scene_count": scene_count,
            "frame_count": frame_count, "split_counts": splits, "files": _dataset_files(root)}


def _seal_holds(root: Path, index: dict, listed: dict[str, list[str]]) -> bool:
    """True when the disk still matches the seal just written: the same shards holding the same
    scene folders, and every shard.json the bytes index.json has the sha256 of."""
    on_disk = {shard.name: names for _, shard in shard_dirs(root)
               if (names := [sdir.name for _, sdir in scene_dirs(shard)])}
    if on_disk != listed:
        return False
    for entry in index["shards"]:
        try:
            if sha256_bytes((root / entry["name"] / SHARD_FILE).read_bytes()) != entry["sha256"]:
                return False
        except FileNotFoundError:
            return False
    return True


def seal_dataset(dataset_dir: str | os.PathLike, max_rounds: int = MAX_SEAL_ROUNDS) -> SealResult:
    """Seal the dataset: bring every shard.json up to date and write index.json (atomically).

    Incremental and safe to rerun at any time (see the module docstring); this is the function a
    cluster's final job calls after its tasks wrote scene ranges. Raises FormatError naming the
    file when a scene not sealed before is damaged (a frame missing or not matching scene.json),
    and DatasetChangingError when writers kept changing the dataset for max_rounds rounds.
    """
    start = time.perf_counter()
    root = Path(dataset_dir)
    if not root.is_dir():
        raise FormatError(f"{root}: dataset directory does not exist")
    scenes_per_shard = read_layout(root)
    result = SealResult(index={})
    for rounds in range(1, max_rounds + 1):
        result.rounds = rounds
        shards, listed = [], {}
        for shard_index, shard in shard_dirs(root):
            seal = seal_shard(shard, shard_index, scenes_per_shard)
            if seal is None:
                continue
            result.scenes_hashed += seal.hashed
            if seal.written:
                result.shards_written.append(shard.name)
            shards.append(seal)
            listed[shard.name] = [scene["name"] for scene in seal.shard_json["scenes"]]
        result.index = build_index(root, scenes_per_shard, shards)
        data = json_bytes(result.index)
        if _read_bytes(root / INDEX_FILE) != data:  # unchanged: no write, no fsync
            atomic_write_bytes(root / INDEX_FILE, data)
        if _seal_holds(root, result.index, listed):
            result.seconds = time.perf_counter() - start
            return result
    raise DatasetChangingError(f"{root}: the dataset kept changing while it was sealed ({max_rounds} "
                               f"rounds); seal it again (`dotsim seal {root}`) when its writers are done")

