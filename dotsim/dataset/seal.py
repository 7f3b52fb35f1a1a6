"""Sealing a dataset: shard.json per shard and index.json, the checksum chain readers verify.

`seal_dataset(DATASET)` seals what is on disk. Run it at any time, as often as wanted, from any
machine that sees the dataset: after one run, after each of many tasks that wrote scene ranges
in any order, or once at the end. It is incremental, so sealing a million scenes after a task
ends costs a listing and the small files, not a re-hash of every frame:

- a shard whose shard.json already lists exactly the complete scenes in its folder, with the
  same scene.json sha256, is kept (its frames are not read);
- a shard that gained or lost scenes gets a new shard.json; only the scenes its old shard.json
  does not list have their frames hashed, and a frame that differs from the sha256 its scene.json
  recorded at write time is refused;
- a scene whose scene.json differs from its entry in the old shard.json was changed after it was
  sealed: it is refused, never hashed into the seal again (`dotsim verify --repair` removes it and
  the generator renders it again); an entry of a shard.json that index.json does not vouch for
  (a seal killed between the two files, or a hand edit) is kept only when it agrees with its
  scene.json, else derived again from the frames;
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


def entry_agrees(entry: dict, sdir: Path, index: int, scene_bytes: bytes) -> bool:
    """True when a shard.json entry says what the scene's scene.json says: its name, index, the
    sha256 of scene.json and each frame's sha256 as scene.json recorded it (no frame is read)."""
    try:
        meta = parse_scene_meta(sdir / SCENE_FILE, scene_bytes)
    except FormatError:
        return False
    files = {SCENE_FILE: sha256_bytes(scene_bytes)} | {e["file"]: e["sha256"] for e in meta["frames"]}
    return (entry.get("name"), entry.get("scene_index"), entry.get("files"),
            entry.get("frame_count")) == (sdir.name, index, files, meta["frame_count"])


def changed_after_sealing(path: Path, shard_path: Path) -> str:
    """The message for a scene.json whose sha256 differs from its sealed entry."""
    return (f"{path}: differs from its entry in {shard_path} (changed after it was sealed; a sealed "
            f"scene is never sealed again with other bytes); {_REPAIR_HINT}")


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


def seal_shard(shard: Path, shard_index: int, scenes_per_shard: int,
               vouched_sha256: str | None = None) -> ShardSeal | None:
    """Bring one shard's shard.json up to date with the complete scenes in its folder; None when
    the shard holds no scene (then it has no shard.json any more).

    vouched_sha256: the sha256 index.json records for this shard.json; when the file has it, its
    entries are trusted as they are, else each entry kept must agree with its scene.json. Raises
    FormatError naming a scene.json that differs from its entry (changed after sealing).
    """
    path = shard / SHARD_FILE
    old_bytes, old_json = _read_shard(path)
    vouched = bool(old_bytes) and sha256_bytes(old_bytes) == vouched_sha256
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
        if old is not None and old.get("files", {}).get(SCENE_FILE) != sha256_bytes(scene_bytes):
            raise FormatError(changed_after_sealing(sdir / SCENE_FILE, path))
        if old is not None and (vouched or entry_agrees(old, sdir, index, scene_bytes)):
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


def index_summary(scenes_per_shard: int, shards: list[tuple[dict, str]], dotsim_version: str) -> dict:
    """index.json's fields but `files`, from (shard.json dict, sha256 of its bytes) of the shards
    that hold scenes, in order: what seal_dataset writes and dotsim verify checks."""
    splits: dict[str, int] = {}
    entries, scene_count, frame_count = [], 0, 0
    for shard, sha in shards:
        for scene in shard["scenes"]:
            splits[str(scene.get("split"))] = splits.get(str(scene.get("split")), 0) + 1
            frame_count += scene["frame_count"]
        scene_count += len(shard["scenes"])
        entries.append({"name": shard["shard"], "scene_count": len(shard["scenes"]), "sha256": sha})
    return {"format_version": FORMAT_VERSION, "dotsim_version": dotsim_version,
            "scenes_per_shard": scenes_per_shard, "shards": entries, "scene_count": scene_count,
            "frame_count": frame_count, "split_counts": splits}


def build_index(root: Path, scenes_per_shard: int, shards: list[ShardSeal]) -> dict:
    """index.json's dict from the seals of the shards that hold scenes, in order."""
    summary = index_summary(scenes_per_shard, [(seal.shard_json, seal.sha256) for seal in shards],
                            DOTSIM_VERSION)
    return summary | {"files": _dataset_files(root)}


def vouched_shards(root: Path) -> dict[str, str]:
    """shard name -> the sha256 index.json records for its shard.json (empty without a readable
    index.json)."""
    try:
        entries = load_json(root / INDEX_FILE).get("shards", [])
        return {e["name"]: e["sha256"] for e in entries if isinstance(e, dict)}
    except (FormatError, KeyError, TypeError, AttributeError):
        return {}


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
        vouched = vouched_shards(root)
        for shard_index, shard in shard_dirs(root):
            seal = seal_shard(shard, shard_index, scenes_per_shard, vouched.get(shard.name))
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

