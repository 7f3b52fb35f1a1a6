"""Checking a whole dataset against its checksums (`dotsim verify`), and repairing it so that a
rerun of the generator redoes exactly the damaged scenes.

verify_dataset reads every file: each frame against the sha256 its scene.json recorded at write
time, each scene against its shard.json, each shard.json and dataset-level file against
index.json, index.json's counts against the shard.json files, and it compares the seal with the
scene folders on disk. Each problem names a file. Only checksums are trusted: a sealed scene
whose scene.json no longer has the sha256 its shard.json entry holds is damaged, whatever its
content says. repair_dataset removes what differs from its seal (damaged scenes, shard.json files
index.json does not vouch for, leftovers of crashed writers) and seals again from what is
intact; it never hashes a changed file into the seal.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from dotsim.dataset.layout import (
    INDEX_FILE,
    LAYOUT_FILE,
    SCENE_FILE,
    SHARD_FILE,
    FormatError,
    parse_index,
    parse_shard,
    read_layout,
    scene_dirs,
    shard_dirs,
    shard_name,
)
from dotsim.dataset.scene_meta import parse_scene_meta
from dotsim.dataset.seal import SealResult, entry_agrees, index_summary, seal_dataset
from dotsim.dataset.writer import leftovers, remove_partial_scenes, remove_scene
from dotsim.file_io import sha256_bytes, sha256_file

# Kinds of problem: a damaged scene (repair removes it; the generator writes it again), a seal
# that is not true to the disk (repair seals again), a shard.json that index.json does not vouch
# for or that disagrees with its scenes (repair removes it; the seal derives it again from the
# intact scenes), a dataset-level file that no longer matches index.json or that it does not list
# (repair cannot know the right bytes; sealing would bless the wrong ones or an unknown file).
SCENE, SEAL, SHARD, FILE = "scene", "seal", "shard", "file"


@dataclass(frozen=True)
class Problem:
    """One thing wrong, naming its file; kind is SCENE, SEAL, SHARD or FILE, scene_index the scene a
    SCENE problem damages."""

    path: Path
    what: str
    kind: str = SEAL
    scene_index: int | None = None

    def line(self) -> str:
        return f"{self.path}: {self.what}"


@dataclass
class VerifyReport:
    """Outcome of verify_dataset: the problems found and what was checked."""

    root: Path
    problems: list[Problem] = field(default_factory=list)
    scenes: int = 0
    frames: int = 0
    absent: list[int] = field(default_factory=list)  # indices below the highest with no scene folder

    @property
    def damaged_scenes(self) -> list[int]:
        return sorted({p.scene_index for p in self.problems if p.kind == SCENE})

    def of_kind(self, kind: str) -> list[Problem]:
        return [p for p in self.problems if p.kind == kind]

    def add(self, path: Path, what: str, kind: str = SEAL, scene_index: int | None = None) -> None:
        self.problems.append(Problem(path, what, kind, scene_index))

    def line(self) -> str:
        checked = f"{self.root}: {self.scenes} scenes, {self.frames} frames checked"
        if not self.problems:
            return f"{checked}: no problems"
        damaged = self.damaged_scenes
        scenes = f" ({len(damaged)} damaged scene(s): {format_indices(damaged)})" if damaged else ""
        return f"{checked}: {len(self.problems)} problem(s){scenes}"


def format_indices(indices: list[int], most: int = 20) -> str:
    """Scene indices for a message: the first `most`, then how many in all."""
    text = ", ".join(map(str, indices[:most]))
    return text + (f" ... ({len(indices)} in all)" if len(indices) > most else "")


def _check_scene(report: VerifyReport, index: int, sdir: Path, sealed: dict | None,
                 shard_file: Path, vouched: bool) -> None:
    """Check one scene folder: scene.json valid, every frame present and matching scene.json, and
    (when shard.json lists it) scene.json matching its shard.json entry, which must also list the
    frames' sha256 as scene.json does. vouched: index.json holds that shard.json's sha256."""
    path = sdir / SCENE_FILE
    try:
        scene_bytes = path.read_bytes()
        meta = parse_scene_meta(path, scene_bytes)
    except FileNotFoundError:
        report.add(path, "missing (the scene folder is damaged)", SCENE, index)
        return
    except FormatError as error:
        report.add(path, str(error).removeprefix(f"{path}: "), SCENE, index)
        return
    report.scenes += 1
    damaged = False
    for entry in meta["frames"]:
        frame = sdir / entry["file"]
        if not frame.is_file():
            report.add(frame, f"missing (listed in {SCENE_FILE})", SCENE, index)
            damaged = True
            continue
        report.frames += 1
        if sha256_file(frame) != entry["sha256"]:
            report.add(frame, f"sha256 differs from the one {SCENE_FILE} recorded at write time "
                              f"(file changed or corrupt)", SCENE, index)
            damaged = True
    if sealed is None:
        return
    if not sealed:
        if not damaged:
            report.add(sdir, f"complete but not sealed (not in {shard_file})")
        return
    if sealed.get("files", {}).get(SCENE_FILE) != sha256_bytes(scene_bytes):
        trust = "" if vouched else f", and {shard_file} does not match {INDEX_FILE} either"
        report.add(path, f"sha256 differs from its entry in {shard_file} (changed after it was "
                         f"sealed{trust}); repair removes the scene", SCENE, index)
    elif not damaged and not entry_agrees(sealed, sdir, index, scene_bytes):
        report.add(shard_file, f"its entry for {sdir.name} does not list the checksums {SCENE_FILE} "
                               f"records; repair derives it again from the frames", SHARD)


def _check_summary(report: VerifyReport, root: Path, index: dict, shards: list[tuple[dict, str]],
                   scenes_per_shard: int) -> None:
    """index.json's counts, shard list and versions against the shard.json files it vouches for."""
    versions = {shard.get("dotsim_version") for shard, _ in shards}
    version = versions.pop() if len(versions) == 1 else index.get("dotsim_version")
    try:
        expected = index_summary(scenes_per_shard, shards, version)
    except (KeyError, TypeError):
        return  # a shard.json of the wrong shape, reported with its shard
    for key, value in expected.items():
        if index.get(key) != value:
            report.add(root / INDEX_FILE, f"{key} is {_short(index.get(key))}, the shard.json files and "
                                          f"{LAYOUT_FILE} say {_short(value)}; sealing again rewrites it")


def _short(value) -> str:
    text = json.dumps(value, sort_keys=True)
    return text if len(text) <= 80 else text[:77] + "..."


def _sealed_shards(report: VerifyReport, root: Path, scenes_per_shard: int
                   ) -> dict[str, tuple[dict[str, dict] | None, bool]]:
    """shard name -> ({scene name -> shard.json entry} or None when unreadable, whether index.json
    vouches for that shard.json) for the shards index.json lists; problems for the index, its
    shards, its summary fields and the dataset-level files."""
    index_path = root / INDEX_FILE
    try:
        index = parse_index(index_path)
    except FormatError as error:
        hint = "" if index_path.exists() else " (the dataset is not sealed)"
        report.add(index_path, str(error).removeprefix(f"{index_path}: ") + hint)
        return {}
    files = index.get("files", {})
    for name, sha in files.items():
        path = root / name
        if not path.is_file():
            report.add(path, f"missing (listed in {INDEX_FILE})")
        elif sha256_file(path) != sha:
            report.add(path, f"sha256 differs from the one in {INDEX_FILE} (file changed or corrupt; "
                             f"restore it, or delete it if `dotsim generate` writes it)", FILE)
    for path in sorted(root.iterdir()):
        if path.is_file() and path.name not in files and path.name != INDEX_FILE \
                and not path.name.startswith("."):
            report.add(path, f"not listed in {INDEX_FILE} (written after the seal); repair does not seal "
                             f"over it: move it out of the dataset, or delete it if `dotsim generate` "
                             f"writes it", FILE)
    sealed: dict[str, tuple[dict[str, dict] | None, bool]] = {}
    vouched_all: list[tuple[dict, str]] = []
    for entry in index.get("shards", []):
        path = root / entry["name"] / SHARD_FILE
        sealed[entry["name"]] = (None, False)
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            report.add(path, f"missing (listed in {INDEX_FILE})")
            continue
        vouched = sha256_bytes(data) == entry["sha256"]
        if not vouched:
            report.add(path, f"sha256 differs from the one in {INDEX_FILE} (a seal was interrupted, "
                             f"or the file changed); repair derives it again from the intact scenes", SHARD)
        try:
            shard = parse_shard(path, data)
        except FormatError as error:
            report.add(path, f"not a valid shard.json ({str(error).removeprefix(f'{path}: ')})", SHARD)
            continue
        sealed[entry["name"]] = ({s["name"]: s for s in shard["scenes"]}, vouched)
        if vouched:
            vouched_all.append((shard, entry["sha256"]))
    if len(vouched_all) == len(index.get("shards", [])):
        _check_summary(report, root, index, vouched_all, scenes_per_shard)
    return sealed


def verify_dataset(dataset_dir: str | os.PathLike) -> VerifyReport:
    """Check completeness and every checksum of a dataset; returns the problems, each naming a file.

    Problems inside a scene (scene.json missing or invalid, or no longer the bytes its shard.json
    entry holds; a frame missing or not matching the sha256 scene.json recorded) mark the scene
    damaged. Problems of the seal (index.json, shard.json, scenes written or removed after
    sealing) are mended by sealing again; a shard.json index.json does not vouch for is derived
    again from its intact scenes.
    """
    root = Path(dataset_dir)
    report = VerifyReport(root)
    if not root.is_dir():
        raise FormatError(f"{root}: dataset directory does not exist")
    scenes_per_shard = read_layout(root)
    for path in leftovers(root):
        report.add(path, "unfinished write left by a crashed writer")
    sealed = _sealed_shards(report, root, scenes_per_shard)
    present = set()
    for shard_index, shard in shard_dirs(root):
        listed, vouched = sealed.get(shard.name, ({}, False))
        listed = None if listed is None else dict(listed)
        for index, sdir in scene_dirs(shard):
            present.add(index)
            if index // scenes_per_shard != shard_index:
                report.add(sdir, f"scene {index} belongs in {shard_name(index // scenes_per_shard)} "
                                 f"(scenes_per_shard={scenes_per_shard})", SCENE, index)
                continue
            _check_scene(report, index, sdir, None if listed is None else listed.pop(sdir.name, {}),
                         shard / SHARD_FILE, vouched)
        for name, entry in (listed or {}).items():
            report.add(shard / name, f"missing (listed in {shard / SHARD_FILE}); sealing again drops it",
                       SEAL, entry.get("scene_index"))
    if present:
        report.absent = sorted(set(range(max(present) + 1)) - present)
    return report


@dataclass
class RepairResult:
    """What repair_dataset did: the scenes it removed (the generator writes them again), the
    shard.json files it removed (derived again by the seal), the leftovers it deleted, and the seal
    it wrote (None when a dataset-level file no longer matches index.json: sealing would record its
    wrong bytes as right)."""

    removed_scenes: list[int]
    removed_shard_files: list[Path]
    removed_leftovers: list[Path]
    seal: SealResult | None


def repair_dataset(report: VerifyReport) -> RepairResult:
    """Remove what a verify_dataset report found differing from its seal, and seal again from what
    is intact, so that rerunning the same `dotsim generate` command writes exactly the removed
    scenes: the damaged scenes, the shard.json files index.json does not vouch for or whose
    entries disagree with their scenes (the seal derives them again from the scenes' own
    checksums) and the leftovers of crashed writers. A changed file is never hashed into the seal.
    A dataset-level file that no longer matches index.json, or that index.json does not list,
    stops the seal: verify flagged it, so the seal must not vouch for it."""
    root = report.root
    scenes_per_shard = read_layout(root)
    removed = [index for index in report.damaged_scenes if remove_scene(root, index, scenes_per_shard)]
    shard_files = sorted({p.path for p in report.of_kind(SHARD) if p.path.is_file()})
    for path in shard_files:
        path.unlink()
    dead_leftovers = remove_partial_scenes(root)
    seal = None if report.of_kind(FILE) else seal_dataset(root)
    return RepairResult(removed, shard_files, dead_leftovers, seal)
