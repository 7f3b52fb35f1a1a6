"""Sealing a dataset: shard.json per shard and index.json, the checksum chain readers verify."""

from __future__ import annotations

import os
from pathlib import Path

from dotsim import __version__ as DOTSIM_VERSION
from dotsim.dataset.layout import (
    FORMAT_VERSION,
    INDEX_FILE,
    SCENE_FILE,
    SHARD_FILE,
    FormatError,
    read_layout,
    scene_dirs,
    shard_dirs,
    shard_name,
)
from dotsim.dataset.scene_meta import parse_scene_meta
from dotsim.file_io import atomic_write_bytes, json_bytes, sha256_bytes, sha256_file


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
    for shard_index, shard in shard_dirs(root):
        scenes = []
        for index, sdir in scene_dirs(shard):
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
        data = json_bytes(shard_json)
        atomic_write_bytes(shard / SHARD_FILE, data)
        shards.append({"name": shard.name, "scene_count": len(scenes), "sha256": sha256_bytes(data)})
        totals["scenes"] += len(scenes)
    extra_files = {p.name: sha256_file(p) for p in sorted(root.iterdir())
                   if p.is_file() and p.name != INDEX_FILE and not p.name.startswith(".")}
    index = {"format_version": FORMAT_VERSION, "dotsim_version": DOTSIM_VERSION,
             "scenes_per_shard": scenes_per_shard, "shards": shards,
             "scene_count": totals["scenes"], "frame_count": totals["frames"],
             "split_counts": splits, "files": extra_files}
    atomic_write_bytes(root / INDEX_FILE, json_bytes(index))
    return index
